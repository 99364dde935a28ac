"""Actuation monitor: delay and gain identification from the controller's own commands."""

from __future__ import annotations

import numpy as np
import pytest

from sanav_mj.control.monitor import ActuationMonitor, MonitorConfig, PoseFilter, PoseFilterConfig

#: [m] half the track of the MuJoCo robot (0.38 m).
HALF_TRACK = 0.19
from sanav_mj.control.unicycle import step_np


def drive(monitor: ActuationMonitor, commands: np.ndarray, delay: int, gains=(1.0, 1.0)) -> None:
    """Feed a plant that applies command k - delay at period k with the given gains."""
    applied = [np.zeros(2)] * delay
    last = np.zeros(2)  # velocity measured at the start of the step (response of the last period)
    for u in commands:
        monitor.update(last)
        monitor.record(u)
        applied.append(np.asarray(u, float))
        last = applied.pop(0) * np.asarray(gains)


def excitation(n: int, seed: int = 0) -> np.ndarray:
    """(n, 2) varied commands (speeds 0-1.4 m/s, yaw rates +-2 rad/s), held for 1-4 steps."""
    rng = np.random.default_rng(seed)
    out, k = [], 0
    while k < n:
        hold = int(rng.integers(1, 5))
        u = np.array([rng.uniform(0.0, 1.4), rng.uniform(-2.0, 2.0)])
        out += [u] * hold
        k += hold
    return np.array(out[:n])


@pytest.mark.parametrize("delay", [0, 1, 2, 3])
def test_identifies_the_delay_and_unit_gains_exactly(delay):
    mon = ActuationMonitor(half_track=HALF_TRACK)
    drive(mon, excitation(60), delay)
    assert mon.delay == delay
    np.testing.assert_allclose(mon.gains, [1.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(mon.residual, [0.0, 0.0], atol=1e-6)


def test_identifies_geometry_gains_with_the_delay():
    # wheel radius x1.1 and track x0.9: the plant drives 10 % faster and turns 22 % faster
    mon = ActuationMonitor(half_track=HALF_TRACK)
    drive(mon, excitation(80, seed=1), delay=1, gains=(1.1, 1.1 / 0.9))
    assert mon.delay == 1
    np.testing.assert_allclose(mon.gains, [1.1, 1.1 / 0.9], rtol=1e-9)


def test_gains_are_clamped():
    mon = ActuationMonitor(MonitorConfig(gain_min=0.8, gain_max=1.2), half_track=HALF_TRACK)
    drive(mon, excitation(60), delay=0, gains=(0.5, 2.0))
    np.testing.assert_allclose(mon.gains, [0.8, 1.2])
    assert mon.residual[0] > 0.1  # what the clamped gains cannot explain shows as residual


def test_pending_holds_the_commands_in_flight_oldest_first():
    mon = ActuationMonitor(half_track=HALF_TRACK)
    cmds = excitation(40, seed=2)
    drive(mon, cmds, delay=2)
    assert mon.delay == 2
    np.testing.assert_array_equal(mon.pending(), cmds[-2:])
    mon.reset()
    assert mon.delay == 0 and mon.pending().shape == (0, 2)
    np.testing.assert_array_equal(mon.gains, [1.0, 1.0])


def test_no_excitation_keeps_the_nominal_delay():
    mon = ActuationMonitor(MonitorConfig(nominal_delay=1), half_track=HALF_TRACK)
    drive(mon, np.zeros((50, 2)), delay=3)  # standing still: nothing to learn from
    assert mon.delay == 1
    np.testing.assert_array_equal(mon.gains, [1.0, 1.0])


def test_constant_cruise_does_not_switch_the_delay():
    mon = ActuationMonitor(half_track=HALF_TRACK)
    cmds = np.concatenate((excitation(40, seed=3), np.tile([[1.0, 0.0]], (60, 1))))
    drive(mon, cmds, delay=2)
    assert mon.delay == 2


def test_max_delay_zero_disables_identification():
    mon = ActuationMonitor(MonitorConfig(max_delay=0), half_track=HALF_TRACK)
    drive(mon, excitation(60), delay=2)
    assert mon.delay == 0 and mon.pending().shape == (0, 2)


def test_non_finite_velocity_is_ignored():
    mon = ActuationMonitor(half_track=HALF_TRACK)
    cmds = excitation(60, seed=4)
    drive(mon, cmds, delay=1)
    before = (mon.delay, mon.gains.copy(), mon.residual.copy())
    mon.update(np.array([np.nan, 0.0]))
    assert mon.delay == before[0]
    np.testing.assert_array_equal(mon.gains, before[1])
    np.testing.assert_array_equal(mon.residual, before[2])


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(max_delay=-1), "max_delay"),
        (dict(max_delay=2, nominal_delay=3), "nominal_delay"),
        (dict(forgetting=1.0), "forgetting"),
        (dict(switch_ratio=0.0), "switch_ratio"),
        (dict(min_excitation=0.0), "min_excitation"),
        (dict(gain_min=1.1), "gain_min"),
    ],
)
def test_config_rejects_bad_values_naming_the_field(kw, match):
    with pytest.raises(ValueError, match=f"MonitorConfig.{match}"):
        MonitorConfig(**kw)


# ------------------------------------------------------------------ pose filter


def noisy_drive(filt: PoseFilter, steps: int, pos_noise: float, yaw_noise: float, seed: int = 0, slip: float = 0.0):
    """Drive a kinematic unicycle (period velocity measured exactly) past ``filt``; ``slip``
    [m/s] is a sideways velocity towards the outside of the turn that (v, w) does not show.

    Returns (true poses, measured poses, estimates), each (steps, 3)."""
    rng = np.random.default_rng(seed)
    x = np.zeros(3)
    true, meas, est = [], [], []
    for k in range(steps):
        u = np.array([1.0, 0.8 * np.sin(0.1 * k)])
        x = step_np(x, u, filt.dt)
        x[:2] -= slip * filt.dt * np.sign(u[1]) * np.array([-np.sin(x[2]), np.cos(x[2])])
        z = x + np.concatenate((rng.normal(0.0, pos_noise, 2), rng.normal(0.0, yaw_noise, 1)))
        true.append(x)
        meas.append(z)
        est.append(filt.update(z, u))
    return np.array(true), np.array(meas), np.array(est)


@pytest.mark.parametrize("slip", [0.0, 0.1, 0.3])
def test_pose_filter_returns_a_noise_free_measurement_exactly_even_with_slip(slip):
    filt = PoseFilter(0.1)
    _, meas, est = noisy_drive(filt, 300, 0.0, 0.0, slip=slip)
    np.testing.assert_array_equal(est, meas)  # slip is not noise: nothing to filter
    np.testing.assert_array_equal(filt.gain, np.ones(3))
    np.testing.assert_array_equal(filt.noise_std, np.zeros(2))


def test_pose_filter_with_noise_and_slip_still_improves_on_the_measurement():
    filt = PoseFilter(0.1)
    true, meas, est = noisy_drive(filt, 600, 0.2, 0.175, seed=2, slip=0.1)
    err_est = np.hypot(*(est[100:, :2] - true[100:, :2]).T)
    err_meas = np.hypot(*(meas[100:, :2] - true[100:, :2]).T)
    assert err_est.mean() < 0.5 * err_meas.mean()


@pytest.mark.parametrize("pos_noise, yaw_noise", [(0.2, 0.175), (0.05, 0.087)])
def test_pose_filter_estimates_the_noise_and_removes_most_of_it(pos_noise, yaw_noise):
    filt = PoseFilter(0.1)
    true, meas, est = noisy_drive(filt, 600, pos_noise, yaw_noise, seed=1)
    err_est = np.hypot(*(est[100:, :2] - true[100:, :2]).T).mean()
    err_meas = np.hypot(*(meas[100:, :2] - true[100:, :2]).T).mean()
    assert err_est < 0.35 * err_meas
    yaw_err = np.abs((est[100:, 2] - true[100:, 2] + np.pi) % (2 * np.pi) - np.pi).mean()
    assert yaw_err < 0.35 * yaw_noise * np.sqrt(2 / np.pi)  # mean |N(0, s)| = s sqrt(2 / pi)
    np.testing.assert_allclose(filt.noise_std, [pos_noise, yaw_noise], rtol=0.4)
    assert np.all(filt.gain < 0.3)


def test_pose_filter_uses_the_measurement_during_warmup_and_follows_its_yaw_branch():
    filt = PoseFilter(0.1, PoseFilterConfig(warmup=5))
    _, meas, est = noisy_drive(filt, 5, 0.1, 0.1)
    np.testing.assert_array_equal(est, meas)
    z = np.array([0.0, 0.0, 2 * np.pi + 0.1])  # an unwrapped yaw stays on its branch
    out = PoseFilter(0.1).update(z, np.zeros(2))
    assert out[2] == z[2]


def test_pose_filter_restarts_from_the_measurement_after_a_real_jump():
    filt = PoseFilter(0.1)
    true, _, _ = noisy_drive(filt, 200, 0.05, 0.0, seed=4)
    assert filt.gain[0] < 0.5 and filt.restarts == 0
    x = true[-1]
    jumped = x + np.array([0.8, 0.0, 0.0])  # relocalised 0.8 m away, then exact
    outs = []
    for _ in range(10):
        outs.append(filt.update(jumped, np.zeros(2)))
    assert filt.restarts >= 1
    np.testing.assert_allclose(outs[-1], jumped, atol=0.05)


def test_pose_filter_passes_through_without_a_velocity_and_restarts():
    filt = PoseFilter(0.1)
    noisy_drive(filt, 100, 0.2, 0.1)
    z = np.array([1.0, 2.0, 0.3])
    np.testing.assert_array_equal(filt.update(z, None), z)
    assert filt.estimate is None
    np.testing.assert_array_equal(filt.update(z + 0.5, np.array([np.nan, 0.0])), z + 0.5)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(odometry_std=0.0), "odometry_std"),
        (dict(odometry_yaw_std=float("inf")), "odometry_yaw_std"),
        (dict(forgetting=1.0), "forgetting"),
        (dict(warmup=-1), "warmup"),
        (dict(max_nis=1.0), "max_nis"),
    ],
)
def test_pose_filter_config_rejects_bad_values_naming_the_field(kw, match):
    with pytest.raises(ValueError, match=f"PoseFilterConfig.{match}"):
        PoseFilterConfig(**kw)


# ------------------------------------------------------------------ traction


def drive_slippery(monitor: ActuationMonitor, commands: np.ndarray, grip_dv: float, w: float = 0.0) -> list[bool]:
    """Feed a plant whose speed moves towards the last command by at most ``grip_dv`` [m/s]
    per period (traction-limited), yaw rate ``w``; returns ``monitor.slipping`` per step."""
    v, out = 0.0, []
    for u in commands:
        monitor.update(np.array([v, w]))
        out.append(monitor.slipping)
        monitor.record(u)
        v += float(np.clip(u[0] - v, -grip_dv, grip_dv))
    return out


def ramp(n: int, rate: float = 0.15, top: float = 1.3) -> np.ndarray:
    """(n, 2) commands: the speed ramps at ``rate`` [m/s per step] to ``top``, yaw rate 0."""
    return np.stack((np.minimum(rate * np.arange(1, n + 1), top), np.zeros(n)), axis=1)


def test_a_traction_limited_plant_is_seen_slipping_and_its_grip_measured():
    # friction 0.05 in MuJoCo: about 0.04 m/s per period while the command ramps at 0.15
    mon = ActuationMonitor(half_track=HALF_TRACK)
    slipping = drive_slippery(mon, ramp(30), grip_dv=0.04)
    assert mon.traction_limited
    assert mon.peak_dv == pytest.approx(0.04, abs=1e-12)
    # at step k the speed is 0.04 k and the commands of the last 6 periods are
    # 0.15 (k - 5) .. 0.15 k, capped at 1.3: the smallest gap 0.15 (k - 5) - 0.04 k exceeds
    # 0.2 m/s from k = 9 on, twice in a row at k = 10; it ends when the speed is within
    # 0.2 m/s of the 1.3 m/s cruise (0.04 k > 1.1: k = 28)
    assert slipping.index(True) == 10
    assert all(slipping[10:28]) and not any(slipping[28:])


@pytest.mark.parametrize("delay", [0, 1, 2, 5])
@pytest.mark.parametrize("gains", [(1.0, 1.0), (0.9, 1.1), (1.1, 1.1 / 0.9)])
def test_a_delayed_plant_with_grip_is_never_taken_for_a_slipping_one(delay, gains):
    # the envelope's geometry errors with any delay in range, under the start-up ramp and
    # under abrupt commands; the identified delay lags behind at first, the check does not
    for commands in (ramp(40), excitation(120, seed=3)):
        mon = ActuationMonitor(half_track=HALF_TRACK)
        applied = [np.zeros(2)] * delay
        last = np.zeros(2)
        for u in commands:
            mon.update(last)
            assert not mon.slipping
            mon.record(u)
            applied.append(np.asarray(u, float))
            last = applied.pop(0) * np.asarray(gains)
        assert not mon.traction_limited


def test_the_peak_speed_change_ignores_fast_turning_periods():
    mon = ActuationMonitor(MonitorConfig(peak_yaw_rate=0.5), half_track=HALF_TRACK)
    drive_slippery(mon, ramp(10), grip_dv=0.04, w=1.0)  # turning: a sliding body's v changes anyway
    assert mon.peak_dv == 0.0
    mon.reset()
    drive_slippery(mon, ramp(10), grip_dv=0.04, w=0.4)
    assert mon.peak_dv == pytest.approx(0.04, abs=1e-12)


def test_slip_detection_can_be_switched_off_and_resets():
    mon = ActuationMonitor(MonitorConfig(slip_gap=None), half_track=HALF_TRACK)
    drive_slippery(mon, ramp(30), grip_dv=0.04)
    assert not mon.traction_limited and not mon.slipping
    mon = ActuationMonitor(half_track=HALF_TRACK)
    drive_slippery(mon, ramp(30), grip_dv=0.04)
    mon.reset()
    assert not mon.traction_limited and not mon.slipping and mon.peak_dv == 0.0


@pytest.mark.parametrize(
    "kw, match",
    [(dict(slip_gap=0.0), "slip_gap"), (dict(slip_periods=0), "slip_periods"), (dict(peak_yaw_rate=-1.0), "peak_yaw_rate")],
)
def test_traction_config_rejects_bad_values_naming_the_field(kw, match):
    with pytest.raises(ValueError, match=f"MonitorConfig.{match}"):
        MonitorConfig(**kw)
