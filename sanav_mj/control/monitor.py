"""Actuation monitor: identify the plant's command delay and gains online from its own commands.

A controller knows every command it sent; the plant reports its measured body velocity
``(v, w)`` at every control step (:class:`~sanav_mj.control.base.Observation`). The velocity
measured at the start of step ``k`` is the plant's response over period ``k - 1``, during which
a plant with a delay of ``d`` control steps applied the command sent at step ``k - 1 - d``.
:class:`ActuationMonitor` fits, for every candidate delay ``d = 0..max_delay``, the
least-squares gains ``v_meas ~ g_v v_cmd`` and ``w_meas ~ g_w w_cmd`` with exponential
forgetting, and takes the delay with the smallest residual (with hysteresis, so that periods
without excitation, e.g. a constant cruise, do not switch it). The gains absorb wheel-radius
and track errors (a wheel 10 % large drives and turns 10 % faster, a track 10 % narrow turns
11 % faster) and, on average, longitudinal slip.

Used by :class:`~sanav_mj.control.sa_mpc.SAMPC` for latency compensation (predict the
state at the instant the new command takes effect from the commands still in flight), for
a speed derating when the velocity tracking residual grows (slip, saturation) and for a
traction estimate (the command running away from the measured speed at every candidate
delay, and the largest speed change per period the body achieved) that lowers the MPC's
rate bound of the speed on a floor that cannot brake at the model's rate.

:class:`PoseFilter` fuses the measured pose with the measured body velocity (an EKF whose
measurement noise is estimated from its own innovations): a noise-free pose passes
unchanged, a noisy one is smoothed by dead reckoning on the measured velocity.

Algorithms only: no printing, no logging; all state is reset per episode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MonitorConfig:
    """Settings of :class:`ActuationMonitor`.

    Attributes:
        max_delay: largest command delay [control steps] considered (0 disables the delay
            identification: the delay is always ``nominal_delay``).
        nominal_delay: [control steps] delay assumed until the data say otherwise.
        forgetting: per-step forgetting factor of the least-squares sums, in (0, 1)
            (0.95: a memory of about 20 steps, 2 s at dt = 0.1 s).
        switch_ratio: a candidate delay replaces the current estimate when its residual is
            below this fraction of the current one, in (0, 1].
        min_excitation: [m^2/s^2] smallest forgotten sum of squared commanded speeds (and
            rim speeds of the yaw rate) before a delay or gain estimate is trusted.
        gain_min, gain_max: clamp of the identified gains (dimensionless; 0.5-2 covers the
            +-20 % geometry corners, whose yaw gain is up to 1.5; at friction 0.05 the
            identified yaw gain reaches the lower clamp).
        slip_gap: [m/s] traction evidence: a period after which the measured speed is
            further than this from the command applied over it *at every candidate delay*
            ``0..max_delay`` (gain 1), on the same side, counts as a traction-limited
            (slipping) period. A plant with grip and a delay in range reaches the command of
            its delay within a period, up to its gain (a gain error of 10 % leaves at most
            0.14 m/s at 1.43 m/s; at friction 0.05 the gap is 0.3-0.5 m/s). None: no
            traction estimate.
        slip_periods: consecutive such periods before the traction limit is trusted.
        peak_yaw_rate: [rad/s] the speed change of a period counts towards ``peak_dv`` only
            if the measured yaw rate at both its ends is at most this: the measured speed is
            the body-frame component, and a body that slides sideways while it turns sees
            it change by ``v_lateral w dt`` without any traction (at friction 0.05: 0.09 m/s
            per period at 1.2 rad/s, twice the 0.045 the floor gives straight ahead).
    """

    max_delay: int = 5
    nominal_delay: int = 0
    forgetting: float = 0.95
    switch_ratio: float = 0.5
    min_excitation: float = 0.5
    gain_min: float = 0.5
    gain_max: float = 2.0
    slip_gap: float | None = 0.2
    slip_periods: int = 2
    peak_yaw_rate: float = 0.5

    def __post_init__(self) -> None:
        if self.slip_gap is not None and not (
            isinstance(self.slip_gap, (int, float)) and math.isfinite(self.slip_gap) and self.slip_gap > 0
        ):
            raise ValueError(f"MonitorConfig.slip_gap must be None or a positive finite number of m/s, got {self.slip_gap!r}")
        if not (isinstance(self.slip_periods, int) and self.slip_periods >= 1):
            raise ValueError(f"MonitorConfig.slip_periods must be an integer >= 1, got {self.slip_periods!r}")
        if not (isinstance(self.max_delay, int) and 0 <= self.max_delay <= 20):
            raise ValueError(f"MonitorConfig.max_delay must be an integer in [0, 20], got {self.max_delay!r}")
        if not (isinstance(self.nominal_delay, int) and 0 <= self.nominal_delay <= max(self.max_delay, 0)):
            raise ValueError(
                f"MonitorConfig.nominal_delay must be an integer in [0, max_delay={self.max_delay}], "
                f"got {self.nominal_delay!r}"
            )
        for name in ("forgetting", "switch_ratio"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v <= 1 and not (name == "forgetting" and v == 1)):
                raise ValueError(f"MonitorConfig.{name} must be in (0, 1), got {v!r}")
        for name in ("min_excitation", "peak_yaw_rate"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"MonitorConfig.{name} must be a positive finite number, got {v!r}")
        if not (isinstance(self.gain_min, (int, float)) and isinstance(self.gain_max, (int, float))
                and 0 < self.gain_min <= 1 <= self.gain_max and math.isfinite(self.gain_max)):
            raise ValueError(
                f"MonitorConfig.gain_min / gain_max must satisfy 0 < gain_min <= 1 <= gain_max < inf, "
                f"got {self.gain_min!r} / {self.gain_max!r}"
            )


class ActuationMonitor:
    """Online identification of the command delay and the velocity gains (see module doc).

    Call :meth:`update` with the measured velocity at the start of each step, then
    :meth:`record` with the command sent at that step.

    Attributes:
        config: the settings.
        half_track: [m] half the robot's track (``RobotParams.track / 2``): converts yaw rates
            into rim speeds so that the v and w residuals are commensurable.
        delay: [control steps] current delay estimate.
        gains: (2,) identified gains ``(g_v, g_w)`` at the current delay, clamped; 1 until
            excited enough.
        residual: (2,) [m/s, rad/s] RMS of the velocity tracking residual at the current
            delay and gains (forgotten), zero until excited.
        peak_dv: [m/s] largest change of the measured speed over one period this episode
            (periods with a yaw rate above ``peak_yaw_rate`` excluded): the floor gives at
            least ``peak_dv / dt`` of grip (a lower bound, whatever was commanded).
        slipping: True while the last ``slip_periods`` consecutive periods each left the
            measured speed more than ``slip_gap`` away from the commands of the last
            ``max_delay + 1`` periods, all on the same side (see "Traction" below).
        traction_limited: ``slipping`` was True at some step of this episode.

    **Traction.** Wheel slip shows as the command running away from the measured speed
    while the plant accelerates at what the floor gives: the commanded-minus-measured
    speed grows beyond what a gain error explains, while the speed changes by a bounded
    amount per period. To not mistake a delayed plant with grip for a slipping one, the
    gap must hold against the command applied at *every* candidate delay (not only the
    identified one, which lags behind at the start of an episode): a plant with a delay
    in range reaches the command of its delay within a period, scaled by its gain. Once
    slip is seen, the largest speed change per period measured so far (``peak_dv``, a
    lower bound of the grip; at friction 0.05 it reads 0.045-0.049 m/s per period, about
    the grip) is the estimate of the acceleration the floor gives. A grippy plant can
    still raise the flag when its gain error leaves more than ``slip_gap`` at speed (a
    gain below 0.86 or above 1.14 at top speed: wheel radius 0.6-0.7 and 1.3-1.4 in
    docs/robustness.md) or its delay exceeds ``max_delay``; flagged after its start-up
    ramp, its ``peak_dv`` is near the model's rate bound and the estimate barely limits
    it, but flagged before any speed change at a low yaw rate (wheel radius 1.3, 7 of 20
    runs) the caller's bound falls to its floor until it recovers.
    """

    def __init__(self, config: MonitorConfig = MonitorConfig(), *, half_track: float):
        if not (isinstance(half_track, (int, float)) and math.isfinite(half_track) and half_track > 0):
            raise ValueError(f"half_track must be a positive finite number of metres, got {half_track!r}")
        self.config = config
        self.half_track = float(half_track)
        self.reset()

    def reset(self) -> None:
        """Forget everything (start of an episode, robot at rest)."""
        m = self.config.max_delay + 1
        self._scale = np.array([1.0, self.half_track**2])  # cost weights of (v, w): (1, half track^2)
        self._hist = np.zeros((m + 1, 2))  # _hist[j] = command sent j + 1 steps ago
        self._svv = np.zeros(2)  # forgotten sum of measured^2 per axis
        self._svc = np.zeros((m, 2))  # per delay: sum measured * command
        self._scc = np.zeros((m, 2))  # per delay: sum command^2
        self._weight = 0.0  # forgotten number of samples
        self._steps = 0
        self.delay = self.config.nominal_delay
        self.gains = np.ones(2)
        self.residual = np.zeros(2)
        self.peak_dv = 0.0
        self.traction_limited = False
        self.slipping = False
        self._slip_run = 0
        self._v_last: float | None = None
        self._w_last = 0.0

    def update(self, velocity: np.ndarray) -> None:
        """Fold in the velocity (2,) [m/s, rad/s] measured at the start of this step.

        Non-finite measurements are ignored.
        """
        vm = np.asarray(velocity, dtype=float).reshape(2)
        if not np.all(np.isfinite(vm)):
            return
        cfg = self.config
        if self._v_last is not None and max(abs(float(vm[1])), self._w_last) <= cfg.peak_yaw_rate:
            self.peak_dv = max(self.peak_dv, abs(float(vm[0]) - self._v_last))
        if self._steps > cfg.max_delay and cfg.slip_gap is not None:
            # gap to the command applied over the last period at every candidate delay: a
            # plant with grip and any delay in range reaches one of them (up to its gain)
            gaps = self._hist[: cfg.max_delay + 1, 0] - float(vm[0])
            if np.all(gaps > cfg.slip_gap) or np.all(gaps < -cfg.slip_gap):
                self._slip_run += 1
            else:
                self._slip_run = 0
            self.slipping = self._slip_run >= cfg.slip_periods
            self.traction_limited = self.traction_limited or self.slipping
        self._v_last = float(vm[0])
        self._w_last = abs(float(vm[1]))
        if self._steps == 0:
            return
        lam = cfg.forgetting
        cand = self._hist[: cfg.max_delay + 1]  # cand[d] = command applied last period if the delay is d
        self._svv = lam * self._svv + vm * vm
        self._svc = lam * self._svc + cand * vm
        self._scc = lam * self._scc + cand * cand
        self._weight = lam * self._weight + 1.0
        scale = self._scale
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(self._scc > 1e-9, self._svc / np.maximum(self._scc, 1e-12), 1.0)
            res = np.maximum(self._svv - np.where(self._scc > 1e-9, self._svc * g, 0.0), 0.0)  # (m, 2)
        cost = res @ scale
        excited = self._scc @ scale >= cfg.min_excitation
        if cfg.max_delay > 0 and excited.any():
            best = int(np.argmin(np.where(excited, cost, np.inf)))
            cur = self.delay
            if best != cur and (not excited[cur] or cost[best] < cfg.switch_ratio * cost[cur]):
                self.delay = best
        d = self.delay
        gd = np.where(self._scc[d] * scale >= cfg.min_excitation * scale, g[d], 1.0)
        self.gains = np.clip(gd, cfg.gain_min, cfg.gain_max)
        if self._weight > 0:
            # residual with the clamped gains: sum (vm - g c)^2 = Svv - 2 g Svc + g^2 Scc
            r = self._svv - 2 * self.gains * self._svc[d] + self.gains**2 * self._scc[d]
            self.residual = np.sqrt(np.maximum(r, 0.0) / self._weight)

    def record(self, command: np.ndarray) -> None:
        """Remember the command (2,) [m/s, rad/s] sent at this step (what the plant receives)."""
        self._hist[1:] = self._hist[:-1].copy()
        c = np.asarray(command, dtype=float).reshape(2)
        # np.nan_to_num changes only non-finite values (5 us a call; finite commands are the rule)
        self._hist[0] = c if math.isfinite(c[0]) and math.isfinite(c[1]) else np.nan_to_num(c)
        self._steps += 1

    def pending(self) -> np.ndarray:
        """(delay, 2) [m/s, rad/s] commands sent but not yet applied, oldest first.

        With a delay of ``d`` steps, the plant applies over the next ``d`` periods the
        commands sent ``d, d - 1, ..., 1`` steps ago; the command computed now takes effect
        after them.
        """
        d = self.delay
        return self._hist[:d][::-1].copy()


@dataclass(frozen=True)
class PoseFilterConfig:
    """Settings of :class:`PoseFilter`.

    Attributes:
        odometry_std: [m] standard deviation of the error of one period's displacement
            integrated from the measured body velocity (the process noise; slip does not
            count, the body velocity is measured, not commanded).
        odometry_yaw_std: [rad] the same for the heading.
        forgetting: per-step forgetting factor of the noise statistics, in (0, 1)
            (0.98: about 50 steps, 5 s at dt = 0.1 s).
        warmup: steps during which the measurement is used as it is (the noise level is not
            known yet).
        max_nis: consistency check: when the forgotten mean of the normalised innovation
            squared (``nu^2`` over its predicted variance, 1 for a consistent filter)
            exceeds this, the filter restarts from the measurement.
    """

    odometry_std: float = 0.005
    odometry_yaw_std: float = 0.01
    forgetting: float = 0.98
    warmup: int = 10
    max_nis: float = 3.0

    def __post_init__(self) -> None:
        for name in ("odometry_std", "odometry_yaw_std"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"PoseFilterConfig.{name} must be a positive finite number, got {v!r}")
        if not (isinstance(self.forgetting, (int, float)) and 0 < self.forgetting < 1):
            raise ValueError(f"PoseFilterConfig.forgetting must be in (0, 1), got {self.forgetting!r}")
        if not (isinstance(self.max_nis, (int, float)) and math.isfinite(self.max_nis) and self.max_nis > 1):
            raise ValueError(f"PoseFilterConfig.max_nis must be a finite number > 1, got {self.max_nis!r}")
        if not (isinstance(self.warmup, int) and self.warmup >= 0):
            raise ValueError(f"PoseFilterConfig.warmup must be an integer >= 0, got {self.warmup!r}")


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class PoseFilter:
    """Fusion of the measured pose with the measured body velocity, for white pose noise (an EKF).

    State: the pose (3,). Per step: predict it from the previous estimate by integrating the
    body velocity measured at the end of the period over the period, on an arc (the wheel
    servos reach a command within a fraction of the period, so under the zero-order hold
    this is the period's velocity: nominal MuJoCo odometry errors are below 3 mm and about
    3 mrad per period outside sharp yaw-rate changes), with the unicycle's Jacobian carrying
    the heading uncertainty into the position; update with the Kalman gain.

    **Noise identification.** The increments ``d_k = (z_k - z_{k-1}) - odometry_k`` of the
    measurements ``z`` against the odometry form a moving average: white measurement noise
    of variance ``R`` gives ``E[d_k d_{k-1}] = -R`` (each noise sample enters two consecutive
    increments with opposite signs), whereas odometry error (lateral slip, which the body
    velocity ``(v, w)`` does not contain, wheel slip) is correlated from one period to the
    next and gives a lag-one covariance >= 0. So ``R = max(0, -E[d_k d_{k-1}])``, forgotten
    over about 5 s, per group (position, yaw); ``R`` below ``odometry_std^2`` counts as 0
    (it underestimates the noise when slip adds a positive covariance: the filter then
    trusts the measurement more, the safe side). With ``R = 0`` the estimate *is* the
    measurement, returned exactly: nominally, and on a slipping floor without pose noise,
    nothing changes. (A first version took ``R`` from the innovations ``z - x_pred``; on a
    floor with friction 0.05 the lateral slip made them large, the filter took the slip for
    noise, trusted the odometry and the estimate drifted: the robot stalled in u_shape.)
    The process noise is ``odometry_std`` per period. **Consistency check**: when the
    forgotten mean of the normalised innovation squared exceeds ``max_nis`` (slip or a
    real jump that the velocity does not explain), the filter restarts from the
    measurement.

    With white noise of std ``sigma`` well above the odometry error the position gain
    falls to about ``odometry_std / sigma`` and the estimate's error is a fraction of the
    measurement's (20 cm: about a seventh). During the first ``warmup`` steps the
    measurement is used as it is.

    Assumes a measured body velocity without bias; without a velocity (``None``) or with
    a non-finite input the measurement is passed through and the filter restarts.

    Attributes:
        estimate: (3,) [m, m, rad] the last estimate, None after a restart.
        gain: (3,) diagonal of the last Kalman gain (1: the measurement was used as it is).
        noise_std: (2,) [m, rad] identified measurement noise std (position per axis, yaw).
        restarts: how often the consistency check restarted the filter this episode.
    """

    def __init__(self, dt: float, config: PoseFilterConfig = PoseFilterConfig()):
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"PoseFilter dt must be a positive finite number of s, got {dt!r}")
        self.dt = float(dt)
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget everything (start of an episode)."""
        self.estimate: np.ndarray | None = None  # (3,) [m, m, rad]
        self._z: np.ndarray | None = None  # last measurement
        self._d: np.ndarray | None = None  # last increment against the odometry
        self._p = np.zeros((3, 3))
        self._s0 = np.zeros(2)  # forgotten sums of d_k^2 (position: mean of x, y), yaw
        self._s1 = np.zeros(2)  # forgotten sums of d_k d_{k-1}
        self._w = 0.0
        self._steps = 0
        self.gain = np.ones(3)
        self.noise_std = np.zeros(2)
        self._nis = np.zeros(2)  # forgotten sums of the normalised innovation squared
        self._nis_w = 0.0
        self.restarts = 0

    def update(self, pose: np.ndarray, velocity: np.ndarray | None) -> np.ndarray:
        """Fold in the measured ``pose`` (3,) and body ``velocity`` (2,) [m/s, rad/s]; returns the estimate (3,)."""
        from sanav_mj.control.unicycle import rollout_np

        z = np.asarray(pose, dtype=float).reshape(3)
        vel = None if velocity is None else np.asarray(velocity, dtype=float).reshape(2)
        if vel is None or not np.all(np.isfinite(vel)) or not np.all(np.isfinite(z)):
            self.reset()
            return z
        cfg = self.config
        q0 = np.array([cfg.odometry_std, cfg.odometry_yaw_std]) ** 2
        if self.estimate is None:
            self.estimate, self._z = z.copy(), z.copy()
            self._p = np.diag(q0[[0, 0, 1]])
            self._steps = 1
            return z
        x = self.estimate
        pred = rollout_np(x, vel[None, :], self.dt)[-1]
        odo = pred - x
        d = z - self._z - odo
        d[2] = float(_wrap(d[2]))
        self._z = z.copy()
        lam = cfg.forgetting
        if self._d is not None:
            self._s0 = lam * self._s0 + np.array([0.5 * (d[0] ** 2 + d[1] ** 2), d[2] ** 2])
            self._s1 = lam * self._s1 + np.array(
                [0.5 * (d[0] * self._d[0] + d[1] * self._d[1]), d[2] * self._d[2]]
            )
            self._w = lam * self._w + 1.0
        self._d = d
        if self._w > 0:
            r = np.maximum(-self._s1 / self._w, 0.0)
            r[r < q0] = 0.0
        else:
            r = np.zeros(2)
        self.noise_std = np.sqrt(r)
        rm = np.diag(r[[0, 0, 1]])
        self._steps += 1
        if self._steps <= cfg.warmup or not np.any(r > 0):
            # the measurement as it is (the prediction's covariance is not needed: computed
            # only below, where it is used)
            self.estimate, self._p = z.copy(), rm + np.diag(q0[[0, 0, 1]])
            self.gain = np.ones(3)
            return z
        q = q0
        th = x[2] + 0.5 * vel[1] * self.dt
        f = np.eye(3)
        f[0, 2] = -vel[0] * self.dt * math.sin(th)
        f[1, 2] = vel[0] * self.dt * math.cos(th)
        p_pred = f @ self._p @ f.T + np.diag(q[[0, 0, 1]])
        nu = z - pred
        nu[2] = float(_wrap(nu[2]))
        s_pred = np.array([0.5 * (p_pred[0, 0] + p_pred[1, 1]), p_pred[2, 2]]) + r
        nis = np.array([0.5 * (nu[0] ** 2 + nu[1] ** 2), nu[2] ** 2]) / s_pred
        self._nis = lam * self._nis + nis
        self._nis_w = lam * self._nis_w + 1.0
        if np.any(self._nis / self._nis_w > cfg.max_nis):
            # the innovations are far larger than the filter expects (a real jump, slip the
            # velocity does not show): restart from the measurement
            self._nis[:] = 0.0
            self._nis_w = 0.0
            self.estimate, self._p = z.copy(), rm + np.diag(q0[[0, 0, 1]])
            self.gain = np.ones(3)
            self.restarts += 1
            return z
        k = p_pred @ np.linalg.inv(p_pred + rm)
        est = pred + k @ nu
        est[2] = z[2] - nu[2] + (k @ nu)[2]  # on the measured yaw's branch
        if r[0] == 0.0:
            est[:2] = z[:2]  # the position is trusted: exactly the measurement
        if r[1] == 0.0:
            est[2] = z[2]
        ik = np.eye(3) - k
        self._p = ik @ p_pred @ ik.T + k @ rm @ k.T  # Joseph form
        self.gain = np.diag(k).copy()
        self.estimate = est
        return est.copy()
