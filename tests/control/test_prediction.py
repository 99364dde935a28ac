"""Derating by the one-step prediction error of the disc centres (``control/prediction.py``)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sanav_mj.control.adaptation import NO_ADAPTATION
from sanav_mj.control.base import Observation
from sanav_mj.control.prediction import PredictionDerating, PredictionMonitor
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig
from sanav_mj.footprint import Footprint

from mpc_cases import ROBOT, make_areas, make_plan

FP = Footprint(-0.25, 0.25, -0.215, 0.215)
OFFSETS = np.array([[-0.5 / 3, 0.0], [0.0, 0.0], [0.5 / 3, 0.0]])


@pytest.mark.parametrize("kw, match", [(dict(free=0.05, stop=0.05), "free"), (dict(floor=0.0), "floor"),
                                       (dict(yaw_floor=1.5), "yaw_floor"), (dict(window=0), "window"),
                                       (dict(free=math.nan), "free")])
def test_config_rejects_bad_values(kw, match):
    with pytest.raises(ValueError, match=match):
        PredictionDerating(**kw)


def test_mpc_config_rejects_a_non_derating():
    with pytest.raises(ValueError, match="footprint_prediction"):
        MPCConfig(footprint_prediction=0.05)


def test_translation_error_is_exact_and_derates_linearly():
    mon = PredictionMonitor(OFFSETS, PredictionDerating(free=0.01, stop=0.06, floor=0.25, yaw_floor=0.3, window=3))
    assert mon.observe(np.array([5.0, 5.0, 0.0])) == 0.0 and mon.error == 0.0  # no prediction yet
    assert mon.fraction() == 1.0
    mon.expect(np.array([1.0, 2.0, 0.7]))
    assert mon.observe(np.array([1.0, 2.035, 0.7])) == pytest.approx(0.035, abs=1e-15)
    assert mon.fraction() == pytest.approx(1.0 - 0.75 * 0.5)  # (0.035 - 0.01) / 0.05 = 0.5
    assert mon.yaw_fraction() == pytest.approx(0.625)
    # a prediction is used once: observing again without one measures nothing
    assert mon.observe(np.array([9.0, 9.0, 0.0])) == 0.0 and mon.error == pytest.approx(0.035)
    mon.expect(np.array([0.0, 0.0, 0.0]))
    mon.observe(np.array([0.0, 0.0, 0.0]))
    assert mon.fraction() == pytest.approx(0.625)  # the window still holds 0.035


def test_rotation_error_is_the_outer_discs_chord_and_the_window_forgets():
    mon = PredictionMonitor(OFFSETS, PredictionDerating(free=0.01, stop=0.06, floor=0.25, yaw_floor=0.3, window=2))
    mon.expect(np.array([0.0, 0.0, 0.0]))
    th = 0.4
    assert mon.observe(np.array([0.0, 0.0, th])) == pytest.approx(2 * (0.5 / 3) * math.sin(th / 2), abs=1e-15)
    assert mon.fraction() == 0.25 and mon.yaw_fraction() == 0.3  # 6.6 cm > stop: the floors
    for _ in range(2):
        mon.expect(np.array([1.0, 1.0, 1.0]))
        mon.observe(np.array([1.0, 1.0, 1.0]))
    assert mon.error == 0.0 and mon.fraction() == 1.0
    mon.reset()
    assert mon.error == 0.0


def _controller(cfg: MPCConfig) -> SAMPC:
    areas = make_areas([[0.0, -0.6, 6.0, 0.6]])
    plan = make_plan(areas, [0], [[0.3, 0.0], [5.7, 0.0]])
    return SAMPC(ROBOT, areas, plan, cfg, footprint=FP)


def _run(ctl: SAMPC, offsets: list[float]) -> list:
    """Steps fed with the pose the last plan predicted, displaced sideways by ``offsets`` [m]."""
    pose = np.array([0.3, 0.0, 0.0])
    out = []
    for k, dy in enumerate(offsets):
        cmd = ctl.step(Observation(t=0.1 * k, pose=pose, velocity=None))
        out.append((cmd, ctl.last))
        pose = np.asarray(cmd.predicted[1], float) + np.array([0.0, dy, 0.0])
    return out


def test_discs_controller_derates_its_bounds_by_the_measured_error():
    cfg = MPCConfig(footprint="discs", footprint_box_margin=0.02, adaptation=NO_ADAPTATION,
                    footprint_prediction=PredictionDerating(free=0.01, stop=0.06, floor=0.25, yaw_floor=0.3))
    ctl = _controller(cfg)
    assert isinstance(ctl.adaptation.prediction, PredictionMonitor)
    steps = _run(ctl, [0.0] * 12 + [0.035, 0.0])
    # nominal: the next effective state is the plan's stage 1, nothing is derated
    assert ctl.adaptation.prediction.error == pytest.approx(0.035, abs=1e-12)
    v_max, w_max = ctl.limits.v_max, ctl.limits.w_max
    free_ub = steps[11][1].input_upper  # before the displacement was seen
    assert free_ub[:, 0].max() > 0.625 * v_max + 0.05
    ub = steps[13][1].input_upper  # after: |v| <= 0.625 v_max, |w| <= 0.625 w_max (reached at the rate bound)
    u_prev = steps[13][1].u_prev
    reach = np.arange(1, ctl.N + 1)[:, None] * ctl.rate_step
    np.testing.assert_array_less(ub[:, 0], np.maximum(0.625 * v_max, u_prev[0] - reach[:, 0]) + 1e-12)
    np.testing.assert_array_less(ub[:, 1], np.maximum(0.625 * w_max, u_prev[1] - reach[:, 1]) + 1e-12)
    assert ub[-5:, 0].max() < free_ub[-5:, 0].max() or ub[:, 0].max() < free_ub[:, 0].max()


def test_disc_mode_and_discs_without_prediction_have_no_monitor():
    assert _controller(MPCConfig()).adaptation.prediction is None
    assert _controller(MPCConfig(footprint="discs", footprint_prediction=None)).adaptation.prediction is None


# ---------------------------------------------------------------- tightening by the error


@pytest.mark.parametrize("kw, match", [(dict(tighten=1), "tighten"), (dict(tighten_extra=-0.001), "tighten_extra"),
                                       (dict(tighten_max=0.0), "tighten_max"),
                                       (dict(tighten_max=math.inf), "tighten_max")])
def test_tightening_config_rejects_bad_values(kw, match):
    with pytest.raises(ValueError, match=match):
        PredictionDerating(**kw)


def test_tightening_is_the_window_maximum_plus_the_constant_capped():
    cfg = PredictionDerating(window=3, tighten_extra=0.002, tighten_max=0.05)
    mon = PredictionMonitor(OFFSETS, cfg)
    assert mon.tightening() == pytest.approx(0.002, abs=1e-15)  # nothing measured: the constant
    for dy in (0.01, 0.035, 0.004):
        mon.expect(np.array([1.0, 0.0, 0.0]))
        mon.observe(np.array([1.0, dy, 0.0]))
    assert mon.tightening() == pytest.approx(0.037, abs=1e-15)  # max(0.01, 0.035, 0.004) + 0.002
    for _ in range(2):  # the window (3 steps) forgets 0.035
        mon.expect(np.array([1.0, 0.0, 0.0]))
        mon.observe(np.array([1.0, 0.003, 0.0]))
    assert mon.tightening() == pytest.approx(0.006, abs=1e-15)  # max(0.004, 0.003, 0.003) + 0.002
    mon.expect(np.array([1.0, 0.0, 0.0]))
    mon.observe(np.array([1.0, 0.2, 0.0]))
    assert mon.tightening() == 0.05  # capped
    off = PredictionMonitor(OFFSETS, replace(cfg, tighten=False))
    off.expect(np.array([1.0, 0.0, 0.0]))
    off.observe(np.array([1.0, 0.2, 0.0]))
    assert off.tightening() == 0.0


def test_discs_controller_tightens_its_stage_boxes_by_the_measured_error():
    cfg = MPCConfig(footprint="discs", footprint_box_margin=0.02, adaptation=NO_ADAPTATION,
                    footprint_prediction=PredictionDerating(free=0.01, stop=0.06, floor=0.25, yaw_floor=0.3,
                                                            tighten_extra=0.002))
    ctl = _controller(cfg)
    steps = _run(ctl, [0.0] * 12 + [0.035, 0.0])
    # the corridor [0, 6] x [-0.6, 0.6] shrunk by box_margin 0.02, then by the tightening:
    # nominally the fed pose is the prediction (error 0): 0.002; after the 0.035 m displacement 0.037
    b = steps[11][1].boxes[1:]
    np.testing.assert_allclose(b[:, 1], -0.58 + 0.002, atol=1e-12)
    np.testing.assert_allclose(b[:, 3], 0.58 - 0.002, atol=1e-12)
    b = steps[13][1].boxes[1:]
    np.testing.assert_allclose(b[:, 1], -0.58 + 0.037, atol=1e-12)
    np.testing.assert_allclose(b[:, 3], 0.58 - 0.037, atol=1e-12)
    # the constraint rows the solver got are these boxes: the accepted plan keeps every disc centre inside
    assert steps[13][0].ok and steps[13][0].margins[1:].min() >= -ctl._check_tol


def test_tightening_off_keeps_the_plain_relaxation():
    cfg = MPCConfig(footprint="discs", footprint_box_margin=0.02, adaptation=NO_ADAPTATION,
                    footprint_prediction=PredictionDerating(tighten=False))
    ctl = _controller(cfg)
    steps = _run(ctl, [0.0] * 4 + [0.035, 0.0])
    np.testing.assert_allclose(steps[5][1].boxes[1:, 3], 0.58, atol=1e-12)


def test_braking_candidates_steer_within_the_derated_yaw_rate_on_the_identified_response():
    cfg = MPCConfig(footprint="discs", footprint_box_margin=0.02, adaptation=NO_ADAPTATION,
                    footprint_prediction=PredictionDerating(free=0.01, stop=0.06, floor=0.25, yaw_floor=0.3))
    ctl = _controller(cfg)
    _run(ctl, [0.0] * 3 + [0.035, 0.0])
    w_max = ctl.limits.w_max
    ctl.adaptation.monitor.gains = np.array([1.1, 1.22])
    wm, gains = ctl.adaptation.brake_response(w_max)
    assert wm == pytest.approx(0.625 * w_max, abs=1e-12)  # yaw fraction at 0.035 m
    np.testing.assert_array_equal(gains, [1.1, 1.22])
    # the plan it brakes with never asks for more than the derated yaw rate beyond the previous one's ramp
    x0 = np.array([1.0, 0.1, 0.2])
    plan = ctl.brake_plan(x0)
    assert np.all(np.abs(plan[:, 1]) <= max(0.625 * w_max, abs(ctl.u_prev[1])) + 1e-12)
    # without the tightening (and in disc mode: no prediction monitor) w_max and the model, as before
    plain = _controller(replace(cfg, footprint_prediction=PredictionDerating(tighten=False)))
    _run(plain, [0.0] * 3 + [0.035, 0.0])
    plain.adaptation.monitor.gains = np.array([1.1, 1.22])
    assert plain.adaptation.brake_response(w_max) == (w_max, None)
    assert _controller(MPCConfig()).adaptation.brake_response(w_max) == (w_max, None)


@pytest.mark.parametrize("dy", [0.035, 0.585])  # the robot inside its boxes; a disc centre 5 mm beyond them
def test_the_shift_check_reads_the_untightened_unrelaxed_boxes_while_moving(dy):
    from sanav_mj.control.disc_stages import DiscCover
    from sanav_mj.control.stages import stage_boxes

    cfg = MPCConfig(footprint="discs", footprint_box_margin=0.02, adaptation=NO_ADAPTATION, footprint_prediction=PredictionDerating())
    ctl = _controller(cfg)
    _run(ctl, [0.0] * 6 + [dy, 0.0])
    assert abs(ctl.u_prev[0]) > 0.02  # moving: no relaxation in the shift check
    info = ctl.last
    con = ctl.constrain(info.guess_states[0], info.x_ref, info.u_ref, info.guess_states)
    ss = con.context[2]
    want_lb, want_ub = DiscCover.bounds(np.array([stage_boxes(ctl.chain, s) for s in ss]))
    lb, ub = con.shift_bounds
    np.testing.assert_array_equal(lb, want_lb)
    np.testing.assert_array_equal(ub, want_ub)
    np.testing.assert_allclose(ub[1::2], 0.58, atol=1e-12)  # corridor half width 0.6 - box_margin 0.02
    if dy < 0.1:  # the rows themselves are tightened by the 0.035 m error + 0.002
        np.testing.assert_allclose(con.pos_ub[1::2], 0.58 - 0.037, atol=1e-12)
    else:  # the rows' widening towards the centre beyond them stops at the untightened box
        assert np.all(con.pos_ub[1::2] <= 0.58 + 1e-12)
    # the problem the fallback checks carries them
    prob = ctl._pose(info.guess_states[0], con, info.guess, info.guess_states)
    assert prob.shift_bounds is con.shift_bounds


# ---------------------------------------------------------------- the estimate's offset (bias)


@pytest.mark.parametrize("kw, match", [(dict(bias_window=0), "bias_window"), (dict(bias_window=True), "bias_window"),
                                       (dict(bias_weight=-0.5), "bias_weight"),
                                       (dict(bias_weight=math.nan), "bias_weight")])
def test_bias_config_rejects_bad_values(kw, match):
    with pytest.raises(ValueError, match=match):
        PredictionDerating(**kw)


def test_bias_is_the_norm_of_the_mean_offset_of_the_measurement_from_the_estimate():
    mon = PredictionMonitor(OFFSETS, PredictionDerating(bias_window=3, tighten_extra=0.002, bias_weight=1.0))
    assert mon.bias == 0.0 and mon.tightening() == pytest.approx(0.002, abs=1e-15)
    est = np.array([1.0, 2.0, 0.0])
    mon.observe_estimate(est, est)  # the filter passed the measurement through
    assert mon.bias == 0.0
    # translations: every disc centre is offset alike; the mean of (0, 0), (0.03, 0.04), (0.03, -0.04) is (0.02, 0)
    mon.observe_estimate(est + [0.03, 0.04, 0.0], est)
    mon.observe_estimate(est + [0.03, -0.04, 0.0], est)
    assert mon.bias == pytest.approx(0.02, abs=1e-15)
    assert mon.tightening() == pytest.approx(0.022, abs=1e-15)  # error 0 + 0.002 + bias
    mon.observe_estimate(est + [0.03, 0.0, 0.0], est)  # the window (3) forgets the zero offset
    assert mon.bias == pytest.approx(0.03, abs=1e-15)
    # a yaw offset moves the outer centres by their distance 1/6 m times the chord factor
    rot = PredictionMonitor(OFFSETS, PredictionDerating(bias_window=1))
    rot.observe_estimate(est + [0.0, 0.0, 0.1], est)
    assert rot.bias == pytest.approx(2 * (0.5 / 3) * math.sin(0.05), abs=1e-15)
    # weighted, capped, and off with the tightening
    half = PredictionMonitor(OFFSETS, PredictionDerating(bias_window=1, bias_weight=0.5, tighten_extra=0.0))
    half.observe_estimate(est + [0.04, 0.0, 0.0], est)
    assert half.tightening() == pytest.approx(0.02, abs=1e-15)
    half.observe_estimate(est + [0.4, 0.0, 0.0], est)
    assert half.tightening() == 0.05
    off = PredictionMonitor(OFFSETS, PredictionDerating(bias_window=1, tighten=False))
    off.observe_estimate(est + [0.04, 0.0, 0.0], est)
    assert off.tightening() == 0.0
    mon.reset()
    assert mon.bias == 0.0


def test_bias_with_the_pass_through_shortcut_equals_the_disc_centre_offsets_bit_for_bit():
    """observe_estimate skips the disc centres when the estimate is the measurement (offsets
    exactly 0) and bias skips the mean of an all-zero window: the same floats as the offsets
    computed from the centres every time (the reference below), over mixed windows."""
    from collections import deque

    from sanav_mj.control.footprint import disc_centres

    rng = np.random.default_rng(3)
    cfg = PredictionDerating(bias_window=4)
    mon, ref = PredictionMonitor(OFFSETS, cfg), deque(maxlen=4)
    for k in range(300):
        meas = rng.normal(size=3) * [5.0, 5.0, 3.0]
        kind = rng.integers(0, 4)
        est = meas.copy() if kind < 2 else (meas + rng.normal(size=3) * 1e-3 if kind == 2 else meas * np.nan)
        if k % 50 == 49:
            est = meas.copy()
            meas[0] = np.nan  # equal bytes would not do: a non-finite pose is never an offset
        mon.observe_estimate(meas, est)
        a, b = disc_centres(np.vstack((meas[None], est[None])), OFFSETS)
        if np.all(np.isfinite(a - b)):
            ref.append(a - b)
        want = 0.0 if not ref else float(np.max(np.hypot(*np.mean(np.asarray(ref), axis=0).T)))
        assert mon.bias == want and math.copysign(1.0, mon.bias) == math.copysign(1.0, want)


def test_the_plant_adaptation_feeds_the_pose_filters_offset_to_the_monitor():
    cfg = MPCConfig(footprint="discs", footprint_prediction=PredictionDerating(bias_window=2, tighten_extra=0.0))
    ctl = _controller(cfg)
    ad = ctl.adaptation
    assert ad.pose_filter is not None
    ad.pose_filter.update = lambda pose, velocity: np.asarray(pose, float) - [0.0, 0.03, 0.0]  # an estimate 3 cm off
    out = ad.filter(np.array([1.0, 0.0, 0.0]), np.zeros(2))
    np.testing.assert_allclose(out, [1.0, -0.03, 0.0], atol=1e-15)
    assert ad.prediction.bias == pytest.approx(0.03, abs=1e-15)
    assert ad.prediction.tightening() == pytest.approx(0.03, abs=1e-15)
    # the disc mode has no monitor: the filter's estimate, nothing else
    disc = _controller(MPCConfig())
    disc.adaptation.pose_filter.update = lambda pose, velocity: np.asarray(pose, float) - [0.0, 0.03, 0.0]
    np.testing.assert_allclose(disc.adaptation.filter(np.array([1.0, 0.0, 0.0]), np.zeros(2)), [1.0, -0.03, 0.0])
    assert disc.adaptation.prediction is None


def _corner_excursion(tmp_path, mpc: MPCConfig) -> tuple[float, dict]:
    """barn_0010 of the 100 BARN-like worlds at the robustness envelope's corner: the largest
    distance [m] of a true disc centre outside every safe area, and the run document."""
    from sanav_mj.control.footprint import disc_centres
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.footprint import robot_footprint
    from sanav_mj.generate import write_barn_scenario
    from sanav_mj.sim.mismatch import Mismatch

    path = write_barn_scenario(10, tmp_path / "barn_0010.xml")
    mm = Mismatch(wheel_radius=1.1, track=0.9, friction=0.3, delay=1, pos_noise=0.02, yaw_noise=0.035)
    out = run_scenario(path, seed=0, mismatch=mm, controller_spec=ControllerSpec("sa-mpc", mpc))
    d = out.document
    rects = np.asarray(out.prepared.areas.rects)
    off = robot_footprint(out.prepared.scenario.model).discs(mpc.footprint_discs)[0]
    c = disc_centres(np.column_stack([d["trace"]["x"], d["trace"]["y"], d["trace"]["yaw"]]), off).reshape(-1, 2)
    dx = np.maximum(np.maximum(rects[None, :, 0] - c[:, None, 0], c[:, None, 0] - rects[None, :, 2]), 0.0)
    dy = np.maximum(np.maximum(rects[None, :, 1] - c[:, None, 1], c[:, None, 1] - rects[None, :, 3]), 0.0)
    return float(np.hypot(dx, dy).min(axis=1).max()), d


def test_corner_run_keeps_the_true_disc_centres_within_the_footprint_margin(tmp_path):
    # Regression (h14safe0): with the stage boxes unshrunk (footprint_box_margin 0), the pose
    # filter's estimate drifted 6.7 cm from the true pose under slip while accepted plans held
    # the *estimate* in the boxes; the true centre left every safe area by 7.5 cm (4.8 cm with
    # the stronger derating alone, bias_weight 0). The bias term of the tightening: 0.0 cm.
    mpc = MPCConfig(footprint="discs")
    assert mpc.footprint_box_margin == 0.0
    exc, d = _corner_excursion(tmp_path, mpc)
    assert d["collisions"] == 0
    assert exc <= mpc.footprint_margin
