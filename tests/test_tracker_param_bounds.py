"""Tracker parameters are bounded so that no accepted value overflows (trackers/params.py, docs/limits.md).

Every float parameter of every filter, associator and the track manager is set in turn to the extremes the
loader accepts (0, the smallest and the largest magnitude), and a tracker using it runs 40 scans of two
crossing targets with clutter, an empty scan and a far-off measurement: every estimate and covariance stays
finite. Values beyond the bounds (1e308, 1e-300, 10^9 scans of history) are refused in one line."""
from __future__ import annotations

import dataclasses
import typing
import warnings

import numpy as np
import pytest

from roadtrack.trackers import ParamError, make_tracker
from roadtrack.trackers.management import ManagementParams
from roadtrack.trackers.params import FLOAT_MAX, FLOAT_MIN
from roadtrack.trackers.registry import ASSOCIATORS, FILTERS

DT = 0.1
CANDIDATES = (0.0, FLOAT_MIN, FLOAT_MAX, -FLOAT_MAX)


def _scans(seed: int = 3, n: int = 40) -> list[np.ndarray]:
    """Two targets crossing at 4 m/s, P_D 0.9, sigma 0.3 m, ~2 clutter points per scan; scan 10 empty, scan 20
    with one measurement 5 km away."""
    rng = np.random.default_rng(seed)
    x = np.array([[0.0, -5.0, 20.0, 2.0], [0.0, 5.0, 20.0, -2.0]])
    out = []
    for k in range(n):
        pos = x[:, :2] + x[:, 2:] * k * DT
        seen = rng.random(2) < 0.9
        z = pos[seen] + 0.3 * rng.normal(size=(int(seen.sum()), 2))
        clutter = pos.mean(axis=0) + rng.uniform(-20, 20, size=(rng.poisson(2), 2))
        scan = np.concatenate([z, clutter]).reshape(-1, 2)
        out.append(np.zeros((0, 2)) if k == 10 else np.vstack([scan, [[5000.0, 5000.0]]]) if k == 20 else scan)
    return out


def _float_fields(cls: type) -> list[str]:
    hints = typing.get_type_hints(cls)
    return [f.name for f in dataclasses.fields(cls)
            if f.init and hints[f.name] in (float, float | None) and "bounds" not in f.metadata]


def _cases() -> list[tuple[str, str, str]]:
    """(tracker name, role, parameter) for every float parameter of every role."""
    cases = [(f"pda-{kind}" if kind != "imm" else "imm-pda-kf", "filter", name)
             for kind, fk in FILTERS.items() for name in _float_fields(fk.params)]
    cases += [(f"{kind}-kf", "associator", name) for kind, ak in ASSOCIATORS.items()
              for name in _float_fields(ak.params)]
    cases += [("jpda-kf", "management", name) for name in _float_fields(ManagementParams)]
    return sorted(set(cases))


def _run(tracker, scans) -> tuple[int, bool]:
    """Scans run and whether every reported estimate and covariance stayed finite."""
    tracks, next_id = (), 1
    for k, Z in enumerate(scans):
        res = tracker.step(tracks, Z, DT if k else 0.0, next_id)
        tracks, next_id = res.tracks, res.next_id
        xs, covs = tracker.kinematics(tracks)
        if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(covs))):
            return k, False
    return len(scans), True


@pytest.mark.parametrize("name, role, key", _cases())
def test_every_accepted_extreme_of_a_float_parameter_runs_finite(name, role, key):
    scans = _scans()
    accepted = 0
    for value in CANDIDATES:
        try:
            tracker = make_tracker(name, **{role: {key: value}})
        except ParamError:
            continue
        accepted += 1
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            done, finite = _run(tracker, scans)
        assert finite, f"{name} {role}.{key} = {value:g}: a non-finite estimate at scan {done}"
    assert accepted >= 1, f"{role}.{key}: no extreme accepted"


@pytest.mark.parametrize("role, key, value, words", [
    ("filter", "sigma_v", 1e308, "must be 0 or of magnitude 1e-09 to 1e+06"),
    ("filter", "sigma_w", 1e-300, "must be 0 or of magnitude"),
    ("associator", "clutter_density", 1e7, "must be 0 or of magnitude"),
    ("management", "history_length", 10**9, "must be in [1, 3000]"),
    ("management", "coast_scans", 10**18, "integers must be within"),
    ("associator", "max_nodes", 2**40, "must be in [1, 1.67772e+07]"),
])
def test_values_beyond_the_bounds_are_refused_in_one_line(role, key, value, words):
    with pytest.raises(ParamError) as info:
        make_tracker("jpda-kf", **{role: {key: value}})
    msg = str(info.value)
    assert msg.startswith(f"{role}.{key}: ") and words in msg and "\n" not in msg


def test_check_refuses_an_overflowing_sigma_v_that_used_to_pass(tmp_path):
    """`testbed check` accepts exactly what `run` can run: sigma_v = 1e308 passed check and overflowed at frame 2."""
    from roadtrack.testbed.cli.check import cmd_check
    from roadtrack.testbed.config.strict import ConfigError
    import argparse

    with pytest.raises(ConfigError) as info:
        cmd_check(argparse.Namespace(file="convoy", set=["tracker.filter.sigma_v=1e308"]))
    assert str(info.value).startswith("tracker.filter.sigma_v: 1e+308 is not allowed")
