"""Background traffic (``[traffic]``, testbed/world/traffic.py), the motorway road and the highway benchmark.

Every run here steps the real highway-env; each test takes a few seconds.
"""
from __future__ import annotations

import numpy as np
from highway_env.road.road import Road
import pytest

from roadtrack.testbed.world import simulation
from roadtrack.testbed.config.strict import ConfigError
from roadtrack.testbed.world.roadside import roadside_boxes
from roadtrack.testbed.pipeline.run import run_scenario
from roadtrack.testbed.sensing import rng_streams
from roadtrack.testbed.scenario.spec import RoadsideSpec, RoadSpec, TrafficSpec, load_scenario, parse_scenario
from roadtrack.testbed.world.simulation import Simulation, build_network, road_edges
from roadtrack.testbed.world.traffic import (IDM_C, TrafficNetwork, TrafficRoad, entry_flux, idm_fit_speed,
                             sample_entry, traffic_rngs)


def _scenario(traffic: dict, seed: int = 0, duration_s: float = 10.0, vehicles: tuple = (), road: dict | None = None,
              ego: dict | None = None):
    return parse_scenario(dict(
        name="traffic_test", seed=seed, duration_s=duration_s,
        road=road or dict(kind="straight", lanes=3, length_m=3000.0),
        ego=ego or dict(lane=1, position_m=500.0, speed_mps=25.0, behaviour="idm"),
        vehicles=list(vehicles), traffic=traffic, tracker=dict(name="jpda-kf")))


def _frames(scn) -> list:
    return list(Simulation(scn).frames())


def _stack(frames) -> tuple[np.ndarray, np.ndarray]:
    """All frames' (ids (N,), [frame, x, y, heading, vx, vy, L, W, H] (N, 9)) rows."""
    ids = np.concatenate([f.ids for f in frames])
    rows = np.concatenate([np.column_stack([np.full(len(f.ids), f.frame), f.xy, f.heading, f.velocity, f.size])
                           for f in frames])
    return ids, rows


def _bumper_gaps(frame, same_direction_lanes: bool = True) -> np.ndarray:
    """Bumper-to-bumper gaps [m] between consecutive vehicles of each (direction, lane) of a frame."""
    gaps = []
    direction = np.sign(frame.velocity[:, 0] + 1e-9 * np.cos(frame.heading))
    for d in (-1.0, 1.0):
        for lane in np.unique(frame.lane):
            m = (direction == d) & (frame.lane == lane)
            order = np.argsort(frame.xy[m, 0])
            x, length = frame.xy[m, 0][order], frame.size[m, 0][order]
            gaps.append(np.diff(x) - 0.5 * (length[1:] + length[:-1]))
    return np.concatenate(gaps)


DENSE = dict(density_per_km_lane=12.0, speed_mps=[23.0, 31.0], mobil_share=0.5, idm_spread=0.1, truck_share=0.2)


def test_traffic_streams_are_the_fourth_child_of_the_seed_and_leave_run_streams_alone():
    # the run's streams are SeedSequence(seed).spawn(3); traffic's are spawn(4)[3].spawn(2): children 0..2 identical.
    seed = 12345
    for i, name in enumerate(("roadside", "lidar", "clutter")):
        child = np.random.default_rng(np.random.SeedSequence(seed).spawn(4)[i])
        np.testing.assert_array_equal(child.random(5), rng_streams(seed)[name].random(5))
    for got, child in zip(traffic_rngs(seed), np.random.SeedSequence(seed).spawn(4)[3].spawn(2)):
        np.testing.assert_array_equal(got.random(5), np.random.default_rng(child).random(5))


def test_no_traffic_by_default_keeps_highway_env_road():
    scn = load_scenario("cut_in_out", {"duration_s": 1.0})
    assert not scn.traffic.enabled and scn.traffic == TrafficSpec()
    sim = Simulation(scn)
    # highway-env's Road, stepped all at once with its numbers (tests/test_stepping.py), no background traffic
    assert sim.traffic is None and type(sim.road).__name__ == "BatchRoad" and type(sim.road).__mro__[1] is Road
    frames = list(sim.frames())
    assert all(len(f.ids) == 4 for f in frames)
    np.testing.assert_array_equal(frames[-1].ids, [0, 1, 2, 3])
    np.testing.assert_allclose(frames[0].size[:, 2], 1.6, atol=1e-12)


def test_same_seed_same_traffic_other_seed_other_traffic():
    a_ids, a = _stack(_frames(_scenario(DENSE, seed=3, duration_s=8.0)))
    b_ids, b = _stack(_frames(_scenario(DENSE, seed=3, duration_s=8.0)))
    np.testing.assert_array_equal(a_ids, b_ids)
    np.testing.assert_array_equal(a, b)  # bit-identical truth for the same seed
    c_ids, c = _stack(_frames(_scenario(DENSE, seed=4, duration_s=8.0)))
    first_a, first_c = a[a[:, 0] == 0], c[c[:, 0] == 0]
    # 3 lanes x 0.7 km x 12 / km = 8.4 per lane: 8 or 9 each
    assert 24 <= len(first_a) - 1 <= 27 and 24 <= len(first_c) - 1 <= 27
    # another seed puts the background cars elsewhere: mean |dx| of the sorted x positions > 10 m
    n = min(len(first_a), len(first_c))
    assert np.mean(np.abs(np.sort(first_a[:n, 1]) - np.sort(first_c[:n, 1]))) > 10.0


def test_count_and_density_fill_the_window_at_the_start():
    # density: 10 / km / lane over 3 lanes x 0.7 km = 21 vehicles (an integer, so exact)
    f0 = _frames(_scenario(dict(density_per_km_lane=10.0), duration_s=0.1))[0]
    x = f0.xy[1:, 0] - f0.xy[0, 0]
    assert len(x) == 21 and np.all((x >= -300.0) & (x <= 400.0))
    per_lane = np.bincount(f0.lane[1:], minlength=3)
    np.testing.assert_array_equal(per_lane, [7, 7, 7])
    # count: exactly 17 vehicles, spread over the lanes in proportion (6, 6, 5)
    f0 = _frames(_scenario(dict(count=17), duration_s=0.1))[0]
    assert len(f0.ids) == 18
    assert sorted(np.bincount(f0.lane[1:], minlength=3).tolist()) == [5, 6, 6]


def test_density_is_kept_over_the_window_in_both_directions():
    """Equal speeds (no IDM queues): time-averaged density over 60 s, 2 seeds, within 15 % of 10 / km / lane.

    Poisson entries make one 60 s run of one 0.7 km lane vary by ~15 %; pooled over 2 seeds and both
    carriageways (3 lanes) the standard error is ~6 %, so 15 % is a 2.5-sigma bound.
    """
    road = dict(kind="motorway", lanes=2, length_m=3000.0)
    ego = dict(lane=0, position_m=500.0, speed_mps=10.0, behaviour="hold_speed")
    traffic = dict(density_per_km_lane=10.0, speed_mps=[25.0, 25.0], lanes=[1])
    dens = {1.0: [], -1.0: []}
    for seed in (0, 1):
        for f in _frames(_scenario(traffic, seed=seed, duration_s=60.0, road=road, ego=ego)):
            x = f.xy[1:, 0] - f.xy[0, 0]
            inside = (x >= -300.0) & (x <= 400.0)
            for sign, n_lanes in ((1.0, 1), (-1.0, 2)):
                dens[sign].append(np.sum(inside & (np.sign(f.velocity[1:, 0]) == sign)) / (0.7 * n_lanes))
    assert dens[1.0][0] == pytest.approx(10.0) and dens[-1.0][0] == pytest.approx(10.0)
    pooled = (np.mean(dens[1.0]) + 2 * np.mean(dens[-1.0])) / 3
    assert pooled == pytest.approx(10.0, rel=0.15)
    assert np.mean(dens[-1.0]) == pytest.approx(10.0, rel=0.2)


def test_entry_speeds_are_weighted_by_their_crossing_rate():
    # speeds U(20, 30) crossing an edge that moves at 25 m/s: E[max(v - 25, 0)] = 25 / 20 = 1.25 m/s
    mean_u, w0, w1 = entry_flux(20.0 - 25.0, 30.0 - 25.0)
    assert mean_u == pytest.approx(1.25, abs=1e-12) and (w0, w1) == (0.0, 5.0)
    rng = np.random.default_rng(0)
    w = np.array([sample_entry(rng, w0, w1) for _ in range(20000)])
    assert np.mean(w) == pytest.approx(10.0 / 3.0, abs=0.03)  # density 2w/25 on [0, 5]: mean 10/3
    assert entry_flux(-10.0, -1.0) == (0.0, 0.0, 0.0)
    assert entry_flux(3.0, 3.0)[0] == pytest.approx(3.0)


def test_start_speed_fits_the_idm_desired_gap():
    # behind a 25 m/s leader with 50 m beyond the jam gap, IDM (T = 1.5 s) wants v T + v (v - 25) / c = 50
    v = idm_fit_speed(50.0, 25.0, 1.5)
    assert v * 1.5 + v * (v - 25.0) / IDM_C == pytest.approx(50.0, abs=1e-9)
    assert 27.0 < v < 28.0 and IDM_C == pytest.approx(2.0 * np.sqrt(15.0), abs=1e-12)
    assert idm_fit_speed(0.0, 25.0, 1.5) == pytest.approx(IDM_C * (25.0 / IDM_C - 1.5), abs=1e-9)
    assert idm_fit_speed(-0.1, 25.0, 1.5) is None


def test_trucks_have_truck_sizes_and_drive_in_truck_lanes():
    traffic = dict(density_per_km_lane=15.0, truck_share=0.5, truck_lanes=[0])
    frames = _frames(_scenario(traffic, seed=2, duration_s=5.0))
    spec = TrafficSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in traffic.items()})
    trucks = cars = 0
    for f in frames:
        for name, size, lane in zip(f.names[1:], f.size[1:], f.lane[1:]):
            truck = name.startswith("truck")
            lo, hi = np.array([spec.truck_length_m, spec.truck_width_m, spec.truck_height_m] if truck
                              else [spec.car_length_m, spec.car_width_m, spec.car_height_m]).T
            assert np.all((size >= lo - 1e-12) & (size <= hi + 1e-12)), (name, size)
            if name.startswith("truck"):
                trucks += 1
                assert lane == 0
            else:
                cars += 1
    first = [n for n in frames[0].names[1:] if frames[0].lane[frames[0].names.index(n)] == 0]
    share = np.mean([n.startswith("truck") for n in first])
    assert 0.2 <= share <= 0.8  # 10 or 11 vehicles in lane 0, half of them trucks
    assert trucks > 0 and cars > 0
    tall = frames[0].size[[n.startswith("truck") for n in frames[0].names], 2]
    assert np.all(tall >= 3.4)  # per-vehicle heights reach the truth


def test_spawns_never_overlap_and_nobody_crashes():
    scn = load_scenario("highway_benchmark", {"duration_s": 15.0, "seed": 7})
    frames = _frames(scn)
    gaps = _bumper_gaps(frames[0])
    assert gaps.min() >= scn.traffic.min_gap_m - 1e-9
    assert not any(f.crashed.any() for f in frames)
    # nothing was spawned on top of the ego: in its lane, at least min_gap_m bumper to bumper
    f0 = frames[0]
    same = np.abs(f0.xy[1:, 1] - f0.xy[0, 1]) < 2.0
    gap = np.abs(f0.xy[1:, 0] - f0.xy[0, 0])[same] - 0.5 * (f0.size[1:, 0][same] + f0.size[0, 0])
    assert gap.min() >= scn.traffic.min_gap_m - 1e-9


def test_scripted_lane_changes_happen_on_time_in_traffic():
    cutter = dict(name="cutter", lane=2, position_m=518.0, speed_mps=25.0, behaviour="idm",
                  lane_changes=[dict(at_s=3.0, lane=1), dict(at_s=9.0, lane=2)])
    scn = _scenario(dict(density_per_km_lane=12.0, position_jitter_m=3.0, speed_jitter_mps=1.0), seed=5,
                    duration_s=12.0, vehicles=(cutter,))
    frames = _frames(scn)
    at = {round(f.time, 1): f for f in frames}
    lane = {t: int(f.lane[1]) for t, f in at.items()}
    assert all(f.ids[1] == 1 and f.names[1] == "cutter" for f in frames)
    assert lane[2.9] == 2 and lane[6.0] == 1 and lane[11.9] == 2
    assert at[2.9].xy[1, 1] == pytest.approx(8.0, abs=0.05)  # still in lane 2 just before 3 s
    assert at[8.9].xy[1, 1] == pytest.approx(4.0, abs=0.3)  # settled in lane 1
    assert not any(f.crashed.any() for f in frames)
    # jitter: the cutter starts within 3 m / 1 m/s of its script, the ego exactly on it
    assert abs(at[0.0].xy[1, 0] - 518.0) <= 3.0 and abs(at[0.0].velocity[1, 0] - 25.0) <= 1.0
    assert at[0.0].xy[0, 0] == 500.0 and at[0.0].velocity[0, 0] == 25.0


def test_window_recycling_bounds_the_vehicle_count_and_never_reuses_ids():
    scn = load_scenario("highway_benchmark", {"duration_s": 60.0, "seed": 1,
                                              "traffic.window_behind_m": 100.0, "traffic.window_ahead_m": 150.0})
    frames = _frames(scn)
    counts = np.array([len(f.ids) for f in frames])
    expected = 8 * 0.25 * 8.0  # lanes x window [km] x density
    assert counts.max() <= 2 * expected + 1 and counts.min() >= 0.4 * expected
    assert np.mean(counts[1:] - 1) == pytest.approx(expected, rel=0.25)
    first, last = {}, {}
    for f in frames:
        assert len(set(f.ids.tolist())) == len(f.ids) and f.ids[0] == 0
        for i in f.ids.tolist():
            first.setdefault(i, f.frame)
            last[i] = f.frame
    present = {i: 0 for i in first}
    for f in frames:
        for i in f.ids.tolist():
            present[i] += 1
    # an id is on the road in one unbroken run of frames: once gone, it never comes back
    assert all(present[i] == last[i] - first[i] + 1 for i in first)
    assert len(first) > 4 * counts.max()  # vehicles were recycled many times over
    ids = sorted(first)
    assert ids == list(range(len(ids)))  # 0, 1, 2, ... in spawn order, no gaps
    assert all(first[a] <= first[b] for a, b in zip(ids, ids[1:]))


def test_vectorised_road_matches_highway_env_road(monkeypatch):
    scn = _scenario(DENSE, seed=9, duration_s=6.0)
    assert isinstance(Simulation(scn).road, TrafficRoad)
    fast_ids, fast = _stack(_frames(scn))
    monkeypatch.setattr(simulation, "TrafficRoad", simulation.Road)
    monkeypatch.setattr(TrafficNetwork, "of", classmethod(lambda cls, net: net))
    sim = Simulation(scn)
    assert type(sim.road).__name__ == "Road" and type(sim.network).__name__ == "RoadNetwork"
    slow_ids, slow = _stack(list(sim.frames()))
    np.testing.assert_array_equal(fast_ids, slow_ids)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-9)


def test_motorway_has_two_carriageways_with_guard_rails_in_the_median():
    spec = RoadSpec(kind="motorway", lanes=4, length_m=1000.0, median_m=4.0)
    net, first = build_network(spec)
    fwd = [net.get_lane((*first, i)) for i in range(4)]
    opp = [net.get_lane(("B", "A", j)) for j in range(4)]
    np.testing.assert_allclose([ln.position(10.0, 0)[1] for ln in fwd], [0.0, 4.0, 8.0, 12.0], atol=1e-12)
    np.testing.assert_allclose([ln.position(10.0, 0)[1] for ln in opp], [32.0, 28.0, 24.0, 20.0], atol=1e-12)
    np.testing.assert_allclose([ln.heading for ln in fwd + opp], [0.0] * 4 + [np.pi] * 4, atol=1e-12)
    edges = road_edges(net)
    ys = sorted(float(np.mean(p[:, 1])) for p, _ in edges)
    np.testing.assert_allclose(ys, [-2.0, 14.0, 18.0, 34.0], atol=1e-9)
    boxes = roadside_boxes(edges, RoadsideSpec(), np.random.default_rng(0))
    y = boxes[:, 1]
    half_w = 0.5 * (boxes[:, 2] * np.abs(np.sin(boxes[:, 5])) + boxes[:, 3] * np.abs(np.cos(boxes[:, 5])))
    assert not np.any((y + half_w > -2.0) & (y - half_w < 14.0))  # nothing on the carriageways
    assert not np.any((y + half_w > 18.0) & (y - half_w < 34.0))
    median = (y > 14.0) & (y < 18.0)
    np.testing.assert_allclose(np.unique(np.round(y[median], 6)), [15.5, 16.5], atol=1e-6)  # two rails
    np.testing.assert_allclose(boxes[median, 2:5], [[4.0, 0.3, 0.75]] * int(median.sum()))
    assert np.sum(y < -2.0) > 250 and np.sum(y > 34.0) > 250  # rails, posts, trees outside


def test_traffic_drives_on_both_carriageways_in_their_directions():
    scn = load_scenario("highway_benchmark", {"duration_s": 2.0})
    f = _frames(scn)[-1]
    fwd = f.velocity[1:, 0] > 0
    assert fwd.sum() > 8 and (~fwd).sum() > 8
    assert np.all(f.xy[1:, 1][fwd] < 14.0) and np.all(f.xy[1:, 1][~fwd] > 18.0)
    np.testing.assert_allclose(np.abs(np.cos(f.heading[1:])), 1.0, atol=0.05)


@pytest.mark.parametrize("override, key, words", [
    ({"traffic.count": 10, "traffic.density_per_km_lane": 5.0}, "traffic.density_per_km_lane", "not both"),
    ({"traffic.densty": 3.0}, "traffic.densty", "unknown key; allowed: car_height_m"),
    ({"traffic.speed_mps": [30.0, 20.0]}, "traffic.speed_mps", "0 <= min <= max"),
    ({"traffic.speed_mps": [20.0]}, "traffic.speed_mps", "expected a list of 2 values"),
    ({"traffic.truck_share": 1.5}, "traffic.truck_share", "must be in [0, 1]"),
    ({"traffic.truck_length_m": [0.0, 10.0]}, "traffic.truck_length_m", "0 < min <= max"),
    ({"traffic.lanes": [0, 5]}, "traffic.lanes", "lane 5 does not exist; allowed: 0..3"),
    ({"traffic.lanes": [-1]}, "traffic.lanes", "lane indices >= 0"),
    ({"traffic.window_ahead_m": -1.0}, "traffic.window_ahead_m", "must be > 0"),
    ({"traffic.idm_spread": 1.0}, "traffic.idm_spread", "in [0, 1)"),
    ({"traffic.mobil_share": "half"}, "traffic.mobil_share", "expected a number"),
    ({"road.kind": "motorwya"}, "road.kind", "allowed: straight, curved, u_turn, motorway"),
    ({"road.median_m": 0.0}, "road.median_m", "must be > 0"),
])
def test_malformed_traffic_keys_are_one_line_errors(override, key, words):
    with pytest.raises(ConfigError) as info:
        load_scenario("highway_benchmark", override)
    msg = str(info.value)
    assert msg.startswith(key + ":") and words in msg and "\n" not in msg, msg


def test_opposite_lanes_need_a_motorway():
    with pytest.raises(ConfigError, match=r"^traffic\.opposite_lanes: road\.kind 'straight' has no opposite"):
        load_scenario("cut_in_out", {"traffic.opposite_lanes": [0]})
    assert load_scenario("cut_in_out", {"traffic.opposite_lanes": []}).traffic.opposite_lanes == ()


def test_highway_benchmark_scenario_is_the_thesis_length():
    scn = load_scenario("highway_benchmark")
    assert scn.duration_s == 427.4 and scn.rate_hz == 10.0 and scn.n_frames == 4275
    assert scn.road.kind == "motorway" and scn.road.lanes == 4 and scn.traffic.enabled
    assert scn.tracker.name == "jpda-kf" and scn.tracker.filter["sigma_w"] == 0.5 and scn.tracker.filter["sigma_v"] == 4.0
    # long enough for the sensor car at 30 m/s for the whole run, window ahead included
    assert scn.road.length_m >= scn.ego.position_m + 30.0 * scn.duration_s + scn.traffic.window_ahead_m


def test_highway_benchmark_first_seconds_end_to_end():
    scn = load_scenario("highway_benchmark", {"duration_s": 3.0})
    res = run_scenario(scn, out_dir=None, record=False)
    assert res.n_frames == 31
    truth = res.tables["truth"]
    frame, ego = truth.array("frame"), truth.array("is_ego")
    xy = np.column_stack([truth.array("x"), truth.array("y")])
    near = []
    for k in range(res.n_frames):
        m = frame == k
        d = np.hypot(*(xy[m & ~ego] - xy[m & ego][0]).T)
        near.append(int(np.sum(d <= 70.0)))
    assert min(near) >= 3  # traffic within the sensor's 70 m in every frame
    prov = res.tables["detections"].array("provenance")
    assert len(np.unique(prov[prov >= 0])) >= 5  # the LiDAR pipeline detected several distinct vehicles
    assert res.scores.cars_seen >= 5


def test_clear_of_lanes_keeps_rails_beside_a_lane_and_drops_boxes_on_it():
    """One straight lane along x (centre y = 0, 4 m wide). A guard rail 0.3 m wide parallel to it at
    y = 2.3 m (0.15 m clear of the edge) stays; the same rail at y = 2.1 m, a 2 m sign panel turned
    across the lane at y = 2.8 m (reaches y = 1.8 m) and a bush on the centre line are left out."""
    from roadtrack.testbed.world.roadside import clear_of_lanes

    s = np.arange(0.0, 101.0)
    centre = np.column_stack([s, np.zeros_like(s)])
    heading, half = np.zeros_like(s), np.full_like(s, 2.0)
    boxes = np.array([[50.0, 2.3, 4.0, 0.3, 0.75, 0.0, 0.0],
                      [50.0, 2.1, 4.0, 0.3, 0.75, 0.0, 0.0],
                      [50.0, 2.8, 2.0, 0.15, 1.2, np.pi / 2, 1.0],
                      [50.0, 0.0, 2.0, 2.0, 1.0, 0.3, 0.0]])
    assert clear_of_lanes(boxes, centre, heading, half).tolist() == [True, False, False, False]
    assert clear_of_lanes(boxes[:0], centre, heading, half).shape == (0,)
