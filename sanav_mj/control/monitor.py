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
state at the instant the new command takes effect from the commands still in flight) and
for a speed derating when the velocity tracking residual grows (slip, saturation).

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
        half_track: [m] converts yaw rates into rim speeds so that the v and w residuals
            are commensurable.
    """

    max_delay: int = 5
    nominal_delay: int = 0
    forgetting: float = 0.95
    switch_ratio: float = 0.5
    min_excitation: float = 0.5
    gain_min: float = 0.5
    gain_max: float = 2.0
    half_track: float = 0.19

    def __post_init__(self) -> None:
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
        for name in ("min_excitation", "half_track"):
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
        delay: [control steps] current delay estimate.
        gains: (2,) identified gains ``(g_v, g_w)`` at the current delay, clamped; 1 until
            excited enough.
        residual: (2,) [m/s, rad/s] RMS of the velocity tracking residual at the current
            delay and gains (forgotten), zero until excited.
    """

    def __init__(self, config: MonitorConfig = MonitorConfig()):
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget everything (start of an episode, robot at rest)."""
        m = self.config.max_delay + 1
        self._hist = np.zeros((m + 1, 2))  # _hist[j] = command sent j + 1 steps ago
        self._svv = np.zeros(2)  # forgotten sum of measured^2 per axis
        self._svc = np.zeros((m, 2))  # per delay: sum measured * command
        self._scc = np.zeros((m, 2))  # per delay: sum command^2
        self._weight = 0.0  # forgotten number of samples
        self._steps = 0
        self.delay = self.config.nominal_delay
        self.gains = np.ones(2)
        self.residual = np.zeros(2)

    def update(self, velocity: np.ndarray) -> None:
        """Fold in the velocity (2,) [m/s, rad/s] measured at the start of this step.

        Non-finite measurements are ignored.
        """
        vm = np.asarray(velocity, dtype=float).reshape(2)
        if self._steps == 0 or not np.all(np.isfinite(vm)):
            return
        cfg = self.config
        lam = cfg.forgetting
        cand = self._hist[: cfg.max_delay + 1]  # cand[d] = command applied last period if the delay is d
        self._svv = lam * self._svv + vm * vm
        self._svc = lam * self._svc + cand * vm
        self._scc = lam * self._scc + cand * cand
        self._weight = lam * self._weight + 1.0
        scale = np.array([1.0, cfg.half_track**2])
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
        self._hist[0] = np.nan_to_num(np.asarray(command, dtype=float).reshape(2))
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
        forgetting: per-step forgetting factor of the innovation statistics, in (0, 1)
            (0.95: about 20 steps, 2 s at dt = 0.1 s).
        warmup: steps during which the measurement is used as it is (the noise level is not
            known yet).
    """

    odometry_std: float = 0.005
    odometry_yaw_std: float = 0.01
    forgetting: float = 0.95
    warmup: int = 10

    def __post_init__(self) -> None:
        for name in ("odometry_std", "odometry_yaw_std"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"PoseFilterConfig.{name} must be a positive finite number, got {v!r}")
        if not (isinstance(self.forgetting, (int, float)) and 0 < self.forgetting < 1):
            raise ValueError(f"PoseFilterConfig.forgetting must be in (0, 1), got {self.forgetting!r}")
        if not (isinstance(self.warmup, int) and self.warmup >= 0):
            raise ValueError(f"PoseFilterConfig.warmup must be an integer >= 0, got {self.warmup!r}")


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class PoseFilter:
    """Noise-adaptive fusion of the measured pose with the measured body velocity (an EKF).

    State: the pose (3,). Per step: predict it from the previous estimate by integrating the
    body velocity measured at the end of the period over the period, on an arc (the wheel
    servos reach a command within a fraction of the period, so under the zero-order hold
    this is the period's velocity: nominal MuJoCo innovations are below 3 mm and about
    3 mrad, outside the first steps and sharp yaw-rate changes), with the unicycle's Jacobian carrying the heading uncertainty into
    the position and the process noise ``odometry_std`` per period; estimate the
    measurement noise covariance ``R = diag(r_p, r_p, r_yaw)`` from the innovations
    ``nu = z - x_pred`` (``E[nu nu^T] = P_pred + R``, forgotten over about 2 s); update with
    the Kalman gain ``K = P_pred (P_pred + R)^-1``. A noise-free measurement gives
    innovations at the odometry error level, ``R = 0`` and ``K = I``: the estimate *is* the
    measurement (returned exactly). With white noise of std ``sigma`` well above the
    odometry error the position gain falls to about ``odometry_std / sigma`` (20 cm
    noise: the estimate's error is about a quarter of the measurement's).

    During the first ``warmup`` steps the measurement is used as it is (the noise level is
    not known yet) and the estimate's covariance is set to the estimated ``R``.

    Assumes white measurement noise and a measured body velocity without bias; without a
    velocity (``None``) or with a non-finite input the measurement is passed through and
    the filter restarts.

    Attributes:
        gain: (3,) diagonal of the last Kalman gain (1: the measurement was used as it is).
        noise_std: (2,) [m, rad] estimated measurement noise std (position per axis, yaw).
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
        self._vel: np.ndarray | None = None
        self._p = np.zeros((3, 3))
        self._nu2 = np.zeros(2)  # forgotten sums: mean sq. position innovation per axis, yaw
        self._pp = np.zeros(2)  # forgotten sums of the matching predicted variances
        self._w = 0.0
        self._steps = 0
        self.gain = np.ones(3)
        self.noise_std = np.zeros(2)

    def update(self, pose: np.ndarray, velocity: np.ndarray | None) -> np.ndarray:
        """Fold in the measured ``pose`` (3,) and body ``velocity`` (2,) [m/s, rad/s]; returns the estimate (3,)."""
        from sanav_mj.control.unicycle import rollout_np

        z = np.asarray(pose, dtype=float).reshape(3)
        vel = None if velocity is None else np.asarray(velocity, dtype=float).reshape(2)
        if vel is None or not np.all(np.isfinite(vel)) or not np.all(np.isfinite(z)):
            self.reset()
            return z
        cfg = self.config
        q = np.diag([cfg.odometry_std**2, cfg.odometry_std**2, cfg.odometry_yaw_std**2])
        if self.estimate is None:
            self.estimate, self._vel, self._p = z.copy(), vel, q.copy()
            self._steps = 1
            return z
        u = vel
        self._vel = vel
        x = self.estimate
        pred = rollout_np(x, u[None, :], self.dt)[-1]
        th = x[2] + 0.5 * u[1] * self.dt
        f = np.eye(3)
        f[0, 2] = -u[0] * self.dt * math.sin(th)
        f[1, 2] = u[0] * self.dt * math.cos(th)
        p_pred = f @ self._p @ f.T + q
        nu = np.array([z[0] - pred[0], z[1] - pred[1], float(_wrap(z[2] - pred[2]))])
        lam = cfg.forgetting
        self._nu2 = lam * self._nu2 + np.array([0.5 * (nu[0] ** 2 + nu[1] ** 2), nu[2] ** 2])
        self._pp = lam * self._pp + np.array([0.5 * (p_pred[0, 0] + p_pred[1, 1]), p_pred[2, 2]])
        self._w = lam * self._w + 1.0
        r = np.maximum((self._nu2 - self._pp) / self._w, 0.0)
        self.noise_std = np.sqrt(r)
        rm = np.diag([r[0], r[0], r[1]])
        self._steps += 1
        if self._steps <= cfg.warmup or not np.any(r > 0):
            self.estimate, self._p = z.copy(), rm + q
            self.gain = np.ones(3)
            return z
        k = p_pred @ np.linalg.inv(p_pred + rm)
        est = pred + k @ nu
        est[2] = z[2] - nu[2] + (k @ nu)[2]  # on the measured yaw's branch
        ik = np.eye(3) - k
        self._p = ik @ p_pred @ ik.T + k @ rm @ k.T  # Joseph form
        self.gain = np.diag(k).copy()
        self.estimate = est
        return est.copy()
