"""The sensed frames of a scenario as one stream: sensed live, or through a sensing cache (each traffic sensed once
into the folder ``run(..., sensing_cache=DIR)`` uses, then read from it), whole or light (testbed.sensing.light).
``testbed.sense`` is this function."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

from ..config import ConfigError
from ..scenario.spec import Scenario
from .cache import SensingCache, check_cache_folder
from .frames import SensedFrame, sense
from .light import lighten
from .registry import scenario_sensors


def sensed_frames(scn: Scenario, policy: Callable | None = None, sensing_cache: str | Path | None = None,
                  light: bool = False) -> Iterator[SensedFrame]:
    """The frames of ``scn`` one by one (an iterator: a frame is made when asked for and held by no one here).

    ``sensing_cache``: a folder (testbed.sensing.cache): the frames are read from its entry for ``scn`` when there,
    else sensed live and stored there once the last one is done (frames from the cache carry no point cloud and
    no perception internals). ``light``: light frames (testbed.sensing.light: no point cloud, a packed range image
    behind the P_D; tens of kB a frame instead of megabytes). ``policy``: the ego's policy for a scenario with
    ``[env]`` (not with a cache: a user's code is not part of the cache's key). Bad arguments are a ConfigError
    (one line) at the call, before anything is sensed."""
    if not isinstance(light, bool):
        raise ConfigError("light", f"expected True or False, got {light!r}")
    if policy is not None and not callable(policy):
        raise ConfigError("policy", f"expected a function f(observation, info) -> action, got "
                          f"{type(policy).__name__}")
    scenario_sensors(scn)  # an unknown sensor of sensor.extra fails at the call
    cache = None
    if sensing_cache is not None:
        if policy is not None:
            raise ConfigError("sensing_cache", "cannot be used with a policy (a user's code is not part of the "
                              "cache's key); sense without the cache")
        cache = SensingCache(check_cache_folder(sensing_cache))
    frames = cache.frames(scn) if cache is not None else sense(scn, policy)
    return lighten(frames, scn) if light else frames
