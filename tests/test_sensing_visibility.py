"""testbed.sensing.lidar.visibility: the LiDAR points on each vehicle of the truth, counted by a table of the vehicle
ids (0..n in a simulated run) or, for large ids (a replayed recording's labels), by the sorted distinct ids; both
give np.unique's counts, and a vehicle with no point gets 0."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from roadtrack.sensors import GROUND, Scan
from roadtrack.testbed.sensing.lidar import visibility


@pytest.mark.parametrize("offset", [0, 10**9])
def test_point_counts_per_vehicle_for_small_and_large_ids(offset):
    rng = np.random.default_rng(4)
    ids = np.array([0, 1, 2, 3, 7]) + offset  # vehicle 3 + offset has no point
    source = rng.choice(np.r_[ids[[0, 1, 2, 4]], -1, GROUND], size=500)
    scan = Scan(points=rng.normal(size=(500, 3)), source=source, origin=np.zeros(3))
    truth = SimpleNamespace(ids=ids, xy=np.array([[0.0, 0.0], [10.0, 0.0], [50.0, 0.0], [99.0, 0.0], [150.0, 0.0]]))
    n_points, in_range = visibility(truth, scan, 100.0)
    expected = np.array([np.count_nonzero(source == i) for i in ids])
    np.testing.assert_array_equal(n_points, expected)
    assert n_points[3] == 0 and n_points.sum() == np.count_nonzero(source >= 0)
    np.testing.assert_array_equal(in_range, [True, True, True, True, False])
