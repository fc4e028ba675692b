"""Moving-object test (testbed/tracking/moving.py) and the sensor pipeline preset (testbed/scenario/spec.py)."""
from __future__ import annotations

import numpy as np
import pytest

from roadtrack.testbed.config.strict import ConfigError
from roadtrack.testbed.tracking.moving import MovingTest, MovingTestSpec
from roadtrack.testbed.scenario.spec import load_scenario


def test_a_static_track_is_never_reported_and_a_moving_one_is_after_its_window():
    test = MovingTest(MovingTestSpec(min_speed_mps=4.0, window_s=0.5))
    rng = np.random.default_rng(0)
    reported = []
    for k in range(30):
        t = 0.1 * k
        bush = np.array([50.0, -8.0]) + rng.normal(0.0, 0.3, 2)  # a static object's estimate: jitter only
        car = np.array([25.0 * t, 0.0]) + rng.normal(0.0, 0.1, 2)
        reported.append(test.update(np.array([1, 2]), np.stack([bush, car]), t))
    reported = np.array(reported)
    assert not reported[:, 0].any()
    assert not reported[:5, 1].any() and reported[5:, 1].all()  # 0.5 s of history to prove it moves


def test_an_initial_velocity_transient_does_not_count_only_displacement_does():
    test = MovingTest(MovingTestSpec(min_speed_mps=4.0, window_s=0.8))
    # a bush's track whose position jumps once by 1.5 m (a new face seen) and stays: 1.5 m / 0.8 s < 4 m/s
    xs = [0.0, 0.0, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5]
    out = [test.update(np.array([3]), np.array([[x, 0.0]]), 0.1 * k)[0] for k, x in enumerate(xs)]
    assert not any(out)


def test_a_car_that_stops_stays_reported_and_a_new_id_starts_afresh():
    test = MovingTest(MovingTestSpec(min_speed_mps=4.0, window_s=0.2))
    for k in range(3):
        test.update(np.array([7]), np.array([[1.0 * k, 0.0]]), 0.1 * k)
    assert test.update(np.array([7]), np.array([[2.0, 0.0]]), 0.3)[0]  # stopped in a jam: still a car
    test.update(np.array([8]), np.array([[0.0, 0.0]]), 0.4)  # 7 deleted, 8 born
    assert not test.update(np.array([7]), np.array([[10.0, 0.0]]), 0.5)[0]  # a re-used id must prove itself again


def test_disabled_reports_everything():
    test = MovingTest(MovingTestSpec(enabled=False))
    assert test.update(np.array([1, 2]), np.zeros((2, 2)), 0.0).all()
    assert test.update(np.zeros(0, np.int64), np.zeros((0, 2)), 0.1).shape == (0,)


def test_thesis_preset_switches_the_stack_to_the_plain_pipeline_but_keeps_explicit_keys():
    full = load_scenario("cut_in_out")
    thesis = load_scenario("cut_in_out", {"sensor.pipeline": "thesis"})
    assert full.sensor.perception.roi and full.sensor.occlusion_pd and full.moving_test.enabled
    assert not thesis.sensor.perception.roi and not thesis.sensor.occlusion_pd and not thesis.moving_test.enabled
    assert thesis.sensor.perception.min_height_mode == "fixed"
    mixed = load_scenario("cut_in_out", {"sensor.pipeline": "thesis", "sensor.perception.roi": True,
                                         "moving_test.enabled": True})
    assert mixed.sensor.perception.roi and mixed.moving_test.enabled and not mixed.sensor.occlusion_pd


def test_bad_pipeline_and_moving_keys_are_one_line_errors():
    with pytest.raises(ConfigError, match=r"^sensor.pipeline: 'paper' is not allowed; allowed: full, thesis$"):
        load_scenario("cut_in_out", {"sensor.pipeline": "paper"})
    with pytest.raises(ConfigError, match=r"^moving_test.window_s: 0.0 is not allowed; must be > 0$"):
        load_scenario("cut_in_out", {"moving_test.window_s": 0})


def test_a_jump_onto_the_next_static_object_and_coasting_on_is_not_motion():
    """A bush's track jumps 3.4 m in two scans onto a neighbouring object and coasts on at 2.7 m/s (measured on
    cut_in_out with roadside objects): over the whole 0.8 s window that is above 4 m/s, over each quarter not."""
    xs = [0.0] * 8 + [2.2, 3.4] + [3.4 + 0.27 * k for k in range(1, 9)]
    whole = MovingTest(MovingTestSpec(min_speed_mps=4.0, window_s=0.8, parts=1))
    quarters = MovingTest(MovingTestSpec(min_speed_mps=4.0, window_s=0.8))
    assert any(whole.update(np.array([1]), np.array([[x, 0.0]]), 0.1 * k)[0] for k, x in enumerate(xs))
    assert not any(quarters.update(np.array([1]), np.array([[x, 0.0]]), 0.1 * k)[0] for k, x in enumerate(xs))


@pytest.mark.parametrize("speed", [4.5, 25.0])
def test_a_car_at_a_steady_speed_is_reported_after_one_window_whatever_the_parts(speed):
    rng = np.random.default_rng(1)
    for parts in (1, 2, 4, 8, 20):
        test = MovingTest(MovingTestSpec(min_speed_mps=4.0, window_s=0.8, parts=parts))
        out = [test.update(np.array([1]), np.array([[speed * 0.1 * k, 0.0]]) + rng.normal(0, 0.01, 2), 0.1 * k)[0]
               for k in range(12)]
        assert not any(out[:8]) and all(out[8:]), (parts, out)


def test_parts_out_of_range_is_a_one_line_error():
    with pytest.raises(ConfigError, match=r"^moving_test.parts: 0 is not allowed; must be in \[1, 20\]$"):
        load_scenario("cut_in_out", {"moving_test.parts": 0})
