"""Every random stream of a run, by name, derived from the scenario seed: the one place that names them.

``generator(seed, name)`` is the stream ``name`` of a run seeded ``seed``. The streams that existed before this
table keep their derivation exactly (:data:`LEGACY`: the spawn key of ``SeedSequence(seed).spawn``'s child they
were, so every earlier output is unchanged); any other name gets ``SeedSequence(seed, spawn_key=(NAMED,
crc32(name)))``: two words whose first, :data:`NAMED`, no legacy key starts with, so a new name never reuses an
existing stream (a name whose crc32 equals another named stream's is refused in one line by :func:`spawn_key`).

A sensor named ``x`` draws from ``sensor.x`` (testbed/sensing/sensor.py); the LiDAR keeps ``lidar`` and ``clutter``.
"""
from __future__ import annotations

import zlib

import numpy as np

LEGACY: dict[str, tuple[int, ...]] = {
    "roadside": (0,),            # roadside objects (testbed.world.simulation.roadside_objects)
    "lidar": (1,),               # LiDAR noise, dropout, attitude (sensors.scan)
    "clutter": (2,),             # added Poisson clutter (sensors.clutter_detections)
    "traffic": (3,),             # parent of the two traffic streams below (never drawn from itself)
    "traffic.jitter": (3, 0),    # start position and speed jitter of scripted vehicles (testbed.world.traffic)
    "traffic.background": (3, 1),  # background traffic (testbed.world.traffic)
}
"""Name -> spawn key of the streams as they were derived before names (``SeedSequence(seed).spawn(4)[3].spawn(2)[1]``
is key (3, 1)); never change a value: every shipped output depends on them."""

NAMED = 0x6E616D65  # "name" in ASCII: the first word of every named stream's spawn key (no legacy key starts so)


def spawn_key(name: str) -> tuple[int, ...]:
    """The spawn key of stream ``name``: its :data:`LEGACY` key, else ``(NAMED, crc32(name))``. ValueError (one
    line) for a name that is not a non-empty string or whose crc32 is a legacy name's."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"a random stream's name must be a non-empty string, got {name!r}")
    if name in LEGACY:
        return LEGACY[name]
    crc = zlib.crc32(name.encode("utf-8"))
    clash = [k for k in LEGACY if zlib.crc32(k.encode("utf-8")) == crc]
    if clash:
        raise ValueError(f"random stream {name!r} has the crc32 of {clash[0]!r}; choose another name")
    return (NAMED, crc)


def seed_sequence(seed: int, name: str) -> np.random.SeedSequence:
    """The SeedSequence of stream ``name`` of a run seeded ``seed`` (an int in [0, 2**32 - 1])."""
    return np.random.SeedSequence(int(seed), spawn_key=spawn_key(name))


def generator(seed: int, name: str) -> np.random.Generator:
    """A fresh generator of stream ``name`` of a run seeded ``seed`` (PCG64, as ``np.random.default_rng``)."""
    return np.random.default_rng(seed_sequence(seed, name))


def check_distinct(names) -> None:
    """ValueError (one line) when two of ``names`` would share a spawn key (a crc32 collision)."""
    seen: dict[tuple[int, ...], str] = {}
    for name in names:
        key = spawn_key(name)
        if key in seen and seen[key] != name:
            raise ValueError(f"random streams {seen[key]!r} and {name!r} would be the same stream; rename one")
        seen[key] = name


class Streams(dict):
    """The generators of one run by name (a dict name -> np.random.Generator): a name is made on first use with
    :func:`generator`, so a consumer asks ``rngs["sensor.radar"]`` and gets a stream no one else draws from."""

    def __init__(self, seed: int, names=()):
        super().__init__()
        self.seed = int(seed)
        for name in names:
            self[name]

    def __missing__(self, name: str) -> np.random.Generator:
        rng = self[name] = generator(self.seed, name)
        return rng
