"""Paper 000 on the highway (testbed.reproduce.seed000.highway): a close LiDAR-seen convoy, one measurement per
frame of unknown origin, gating and the KS integral test; the quick report.

Measured on the quick run (seed 0, 1 run of 51 frames per gap and pipeline, gaps 0.25 and 4 m): at 4 m no
measurement is wrong in either pipeline and the KS test flags 0 of 50 clean ones (bound here: at most 5 %); at
0.25 m the target has a detection of its own in 12 % (full) / 0 % (thesis) of the frames, 86 % (full, 19 of 22) /
100 % (thesis, 7 of 7) of the measurements are wrong, all of them neighbours' boxes or roadside objects (no merged
two-car detection reaches the filter); the gated filter's RMS error is 2.7 / 1.7 m against 15.6 / 59.7 m
without gating; the KS test flags all 19 wrong measurements of the full pipeline.
"""

from __future__ import annotations

import numpy as np
import pytest

from roadtrack.testbed.reproduce.seed000 import highway as h
from roadtrack.trackers.filters.kalman import KalmanFilter
from roadtrack.trackers.models import ConstantVelocity, PositionMeasurement


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    res = h.compute(h.QUICK, seed=0)
    out = tmp_path_factory.mktemp("seed000_highway")
    return res, h.write_report(res, out, quick=True)


def test_quick_report_writes_its_summary_and_figures(quick):
    res, path = quick
    assert path.name == "summary.md" and path.exists()
    for name in h.FIGURES:
        png = path.parent / name
        assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert f"]({name})" in path.read_text()
    text = path.read_text()
    assert "| quantity | paper 000 (point targets) | ours, full pipeline | ours, thesis pipeline |" in text
    assert text.count("| 0.25 | 50 |") == 2 and text.count("| 4 | 50 |") == 2  # one row per gap and pipeline


def test_widest_gap_has_no_wrong_measurement_and_few_ks_flags(quick):
    res, _ = quick
    wide = res.settings.gaps[-1]
    for pipe in res.settings.pipelines:
        c = res.cells[(wide, pipe)]
        assert c.n_wrong == 0 and c.n_meas == c.frames and c.detected == 1.0, (pipe, c.n_wrong, c.detected)
        assert c.ks_clean == c.n_meas and c.ks_false <= 0.05, (pipe, c.ks_false)
        assert c.rmse_gated < 0.3 and abs(c.rmse_ungated / c.rmse_gated - 1.0) < 0.1, pipe  # nothing to gate


def test_smallest_gap_mixes_and_gating_limits_the_damage(quick):
    res, _ = quick
    near = res.settings.gaps[0]
    thesis, full = res.cells[(near, "thesis")], res.cells[(near, "full")]
    assert thesis.mixing > 0.5 and thesis.n_wrong >= 3, thesis.mixing
    assert full.mixing > 0.5 and full.n_wrong >= 10, full.mixing
    for c in (thesis, full):
        assert c.detected < 0.5 and c.too_long > 0.8, (c.pipeline, c.detected, c.too_long)  # joined, rejected
        assert c.rmse_ungated > 3.0 * c.rmse_gated, (c.pipeline, c.rmse_gated, c.rmse_ungated)
        assert c.sep_median > 4.0, c.sep_median  # a neighbour's box or a roadside object, not a centre in between
    assert full.ks_wrong == full.n_wrong and full.ks_detected >= 0.9, full.ks_detected


def test_detection_kinds_from_provenance_and_owners():
    prov = np.array([7, 8, -1, 7, 8])
    owners = np.array([1, 1, 0, 2, 3])
    np.testing.assert_array_equal(h.detection_kinds(prov, owners, 7), [0, 1, 2, 3, 3])


def _sensed(z_wrong: np.ndarray) -> h.Sensed:
    """A target at 20 m/s along x, sensed exactly every 0.1 s; at frame 5 only a detection at z_wrong (kind 1)."""
    K, dt = 12, 0.1
    t = dt * np.arange(K)
    truth = np.column_stack([20.0 * t, np.zeros(K), np.full(K, 20.0), np.zeros(K)])
    z = [truth[k, None, :2].copy() for k in range(K)]
    kind = [np.zeros(1, np.int64) for _ in range(K)]
    z[5], kind[5] = z_wrong[None], np.ones(1, np.int64)
    return h.Sensed(t=t, truth=truth, z=z, kind=kind, flagged=[np.zeros(1, bool)] * K,
                    too_long=np.zeros(K, bool), dt=dt)


def test_follow_gates_out_a_neighbour_the_ungated_filter_takes():
    """A neighbour's box 5.25 m ahead (10.5 sigma of R) at frame 5: the gamma 9 gate drops it, the plain KF is pulled
    by it (its innovation norm 5.25 m, gain about 0.5)."""
    s = _sensed(np.array([20.0 * 0.5 + 5.25, 0.0]))
    flt = KalmanFilter(motion=ConstantVelocity(4.0), measurement=PositionMeasurement(0.5))
    g = h.follow(s, flt, h.FILTERS["gated"][1], search_m=10.0)
    u = h.follow(s, flt, h.FILTERS["ungated"][1], search_m=10.0)
    assert g.wrong.sum() == 1 and g.wrong[4] and not g.validated[4] and g.validated[np.arange(11) != 4].all()
    assert u.validated.all() and abs(np.linalg.norm(u.nu[4]) - 5.25) < 1e-9
    assert g.error(s)[4] < 0.05 and u.error(s)[4] > 1.5, (g.error(s)[4], u.error(s)[4])
    far = h.follow(_sensed(np.array([10.0 + 12.0, 0.0])), flt, h.FILTERS["gated"][1], search_m=10.0)
    assert not far.has[4] and far.has.sum() == 10  # beyond the search window: no measurement, the filter coasts


def test_ks_flags_an_isolated_wrong_measurement_and_no_clean_one():
    """Clean innovation norms about 0.05 m; one wrong measurement 5 m off: every window holding it is above the
    threshold, and only it is flagged."""
    rng = np.random.default_rng(3)
    ref = h.KsReference(x=np.abs(rng.normal(0.0, 0.05, 500)), n=10, k_sigma=3.0, threshold=0.05, mu0=0.04)
    nu = np.column_stack([rng.normal(0.0, 0.05, 40), np.zeros(40)])
    nu[20] = [5.0, 0.0]
    kind = np.zeros(40, np.int64)
    kind[20] = 1
    fol = h.Followed(kind=kind, flagged=np.zeros(40, bool), z=nu, nu=nu, S=np.tile(np.eye(2), (40, 1, 1)),
                     d2=np.zeros(40), validated=np.ones(40, bool), x=np.zeros((40, 4)))
    s = h.Sensed(t=0.1 * np.arange(41), truth=np.zeros((41, 4)), z=[], kind=[], flagged=[],
                 too_long=np.zeros(41, bool), dt=0.1)
    k = h.ks_run(fol, s, ref)
    assert len(k.D) == 31 and np.flatnonzero(k.flagged).tolist() == [20]
    assert np.all(k.D[11:21] > 0.4)  # the hump: (5 - mu) / n in each of the n windows holding it


def test_sensing_is_seeded():
    st = h.Settings(gaps=(0.5,), runs=1, lead_m=1.0, closing_mps=4.0, reference_runs=1, pipelines=("thesis",))
    a, b = (h.sense(h.scenario(st, 0.5, "thesis", 11)) for _ in range(2))
    assert len(a.t) == 6 and all(np.array_equal(x, y) for x, y in zip(a.z, b.z))
    assert np.array_equal(a.truth, b.truth) and all(np.array_equal(x, y) for x, y in zip(a.kind, b.kind))
