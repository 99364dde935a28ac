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
