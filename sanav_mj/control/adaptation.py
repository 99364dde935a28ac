"""The adaptation of a tracking MPC to the plant it drives: one object, one frozen config.

:class:`PlantAdaptation` owns the :class:`~sanav_mj.control.monitor.ActuationMonitor` and the
:class:`~sanav_mj.control.monitor.PoseFilter`. The MPC core (:mod:`sanav_mj.control.tracking`)
asks it, every step, for

- the measured state to plan from (:meth:`PlantAdaptation.observe`: monitor update, pose
  filter) and the state at which the next command takes effect
  (:meth:`PlantAdaptation.effective_state`, latency compensation);
- the rate bound of the speed (:meth:`PlantAdaptation.traction_accel`, traction limit) and
  the speed / yaw-rate caps (:meth:`PlantAdaptation.speed_cap`,
  :meth:`PlantAdaptation.residual_cap`, :meth:`PlantAdaptation.residual_yaw_cap`);
- the command actually sent for a planned input (:meth:`PlantAdaptation.send`: gain
  compensation, clipping, recorded in the monitor).
- in SA-MPC's ``"discs"`` mode, the speed / yaw-rate caps from the one-step prediction error
  of the footprint (:meth:`PlantAdaptation.prediction_cap`, :mod:`sanav_mj.control.prediction`:
  :meth:`PlantAdaptation.effective_state` compares the state with what the last planned input
  predicted, :meth:`PlantAdaptation.send` records the next prediction); off elsewhere.

Robot-derived values (the half track that makes yaw-rate residuals commensurable with
speeds) come from the robot's parameters. The excursion derating is described in
:class:`~sanav_mj.control.sa_mpc.SAMPC` ("Measured position outside its box"); the other
mechanisms, with their rationale and measurements, below (as seen from SA-MPC).
:data:`NO_ADAPTATION` switches every mechanism off (the penalty MPC's plant view).

**Derating by tracking residual.** Slip (low friction), a saturated actuator (small
torque limit) or a delay beyond what the monitor identifies make the measured body
velocity differ from the identified response to the sent commands. The monitor's RMS
residual over its forgetting window lowers the speed bound like an excursion does
(``AdaptationConfig.residual_stop``): a plant that does not do what it is told is driven
slowly, down to ``residual_floor v_max``, so that its braking distance and the error
it accumulates per period shrink with the speed.

The same fraction lowers the yaw-rate bound (not below ``residual_yaw_floor w_max``):
at low friction with an over-turning plant the loop weaves at up to +-2 rad/s while
driving at 0.8 m/s, asking for more lateral acceleration than the floor gives; derating
both inputs cuts the asked-for ``v w`` with the square of the fraction.

**Traction limit.** The residual measures the tracking error, not the braking
capability: on a floor with 0.36-0.49 m/s^2 of grip (friction 0.05) the identified
speed gain drops to its clamp, absorbs the slow ramp, and the residual stays near
0.04 m/s while the commanded speed runs 0.5 m/s ahead of the measured one; the robot
reached 0.93 m/s with the model braking at 1.5 m/s^2 and slid out of its corridor at a
corner. The monitor flags slip when the measured speed stays more than
``monitor.slip_gap`` from the commands of *every* candidate delay (a delayed plant with
grip reaches the command of its delay, so it is not mistaken for a slipping one), and
keeps the largest speed change per period the body achieved (a lower bound of the grip;
periods of fast turning excluded). While slip is seen, the rate bound of the speed
becomes ``traction_probe`` times that grip (not below ``traction_floor a_max``); every
bound derived from ``a_max`` follows, per solve: the rate constraints, the speed bounds
implied by the terminal stop (so each plan can stop inside its stage boxes at the
grip the plant showed) and the braking fallback. Without slip the bound recovers by
``traction_recovery`` per step. In the envelope and the nominal runs the flag is never
raised, so nothing changes there (every run bit-identical); a plant whose gain error
exceeds about 15 % at speed is flagged like a slipping one (docs/robustness.md).

**Pose filter.** Before anything else the measured pose is fused with the measured body
velocity by a :class:`~sanav_mj.control.monitor.PoseFilter` (an EKF whose measurement
noise is identified online from the lag-one covariance of the measurement increments
against the odometry, so slip is not taken for noise). A noise-free pose (nominal, and
on a slipping floor) is returned exactly, so the nominal controller is unchanged; under
white noise of 5-20 cm the estimate's error is a third to a seventh of the
measurement's (synthetic check). A real jump (relocalisation) is followed after the
filter's consistency restart.

**Latency compensation.** A plant that applies each command ``d`` control steps late
(actuator and communication latency) makes an MPC that plans from the measured state
weave: its first input takes effect ``d dt`` later than it assumes. The controller knows
the commands it sent; the :class:`~sanav_mj.control.monitor.ActuationMonitor` identifies
``d`` (0..``monitor.max_delay``) and the gains ``(g_v, g_w)`` online from the measured body
velocity (least squares with forgetting, per candidate delay; smallest residual wins,
with hysteresis). Each step rolls the measured pose forward through the ``d`` commands
already sent and not yet applied (scaled by the gains) and poses the problem from that
predicted state, with the last sent input as ``u_prev``. The stage-0 position of every
argument below is then that prediction; the positions between the measurement and it
were planned by the earlier solves that sent those commands. Assumed: the delay is an
integer number of periods and constant over the forgetting horizon (about 2 s); a wrong
estimate shows up as tracking error like any other mismatch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sanav_mj.control.monitor import ActuationMonitor, MonitorConfig, PoseFilter, PoseFilterConfig
from sanav_mj.scene import RobotParams


def _check(name: str, ok: bool, rule: str, value) -> None:
    if not ok:
        raise ValueError(f"AdaptationConfig.{name} must be {rule}, got {value!r}")


@dataclass(frozen=True)
class AdaptationConfig:
    """Settings of :class:`PlantAdaptation`.

    Attributes:
        latency_compensation: predict the state at the instant the new command takes effect
            through the commands already sent but not yet applied, using the delay and gains
            identified online by the :class:`~sanav_mj.control.monitor.ActuationMonitor`
            (see "Latency compensation" in :class:`~sanav_mj.control.sa_mpc.SAMPC`).
        gain_compensation: divide each sent command by the identified gains, so that the
            plant realises the planned velocity (off by default: not needed in the measured
            envelope, see docs/robustness.md).
        monitor: settings of the actuation monitor (delay range, forgetting, gain clamp).
        pose_filter: settings of the :class:`~sanav_mj.control.monitor.PoseFilter` that
            fuses the measured pose with the measured body velocity before each step (it
            returns a noise-free measurement exactly; see "Pose filter" in :class:`~sanav_mj.control.sa_mpc.SAMPC`).
            None: the measured pose is used as it is.
        excursion_stop: [m] speed derating when the position (at the instant the command
            takes effect) lies outside its stage box by ``e``: the speed bound becomes
            ``v_max max(derate_floor, 1 - e / excursion_stop)``, reached at the rate bound
            (see "Measured position outside its box"). None: no derating.
        derate_floor: fraction of ``v_max`` the excursion derating never goes below (so
            that a robot slightly outside its box still makes progress back in).
        residual_free, residual_stop: [m/s] speed derating by the actuation monitor's
            velocity-tracking residual ``r`` (RMS over about 2 s of the measured minus the
            identified response, the yaw rate counted as rim speed): none up to
            ``residual_free``, then linear down to ``residual_floor v_max`` at
            ``residual_stop`` and beyond (see "Derating by tracking residual"). Measured
            residuals: below 0.006 m/s nominal, median 0.01-0.04 m/s in the envelope's
            worst corner, 0.07-1 m/s at friction 0.05-0.1 or a torque limit of 10 %
            (docs/robustness.md). None: no residual derating.
        residual_floor: fraction of ``v_max`` the residual derating never goes below.
        residual_yaw_floor: the residual derating lowers the yaw-rate bound by the same
            fraction as the speed bound, but never below this fraction of ``w_max`` (so the
            robot can still turn towards its corridor); the lateral acceleration ``v w`` a
            plant that does not follow is asked for falls with the square of the fraction.
            None: the yaw rate is not derated.
        traction_probe: speed rate bound from the monitor's traction evidence (see
            "Traction limit" in :class:`~sanav_mj.control.sa_mpc.SAMPC`): while the monitor sees the plant slip, the
            rate bound of the speed (and with it the speed bounds implied by the terminal
            stop and the braking fallback) is this factor times the largest speed change
            per period the body achieved this episode, over ``dt`` (above 1: room for the
            plant to show more grip). None: the model's ``a_max`` throughout.
        traction_floor: fraction of ``a_max`` the traction bound never goes below.
        traction_recovery: per-step relative growth of the traction bound back towards
            ``a_max`` while no slip is seen (0.05: from the floor to ``a_max`` in about
            5 s).
        fallback_derated: on a rejected solve, check the shifted previous plan against the
            *derated* input bounds as well: a plan that keeps a speed (or yaw rate) above the
            current derating is not followed, the robot brakes (it used to follow its old
            plan at 1.06 m/s on a floor where the derating asked for 0.65, docs/robustness.md).
    """

    latency_compensation: bool = True
    gain_compensation: bool = False
    monitor: MonitorConfig = MonitorConfig()
    pose_filter: PoseFilterConfig | None = PoseFilterConfig()
    excursion_stop: float | None = 0.15
    derate_floor: float = 0.25
    residual_free: float = 0.03
    residual_stop: float | None = 0.2
    residual_floor: float = 0.1
    residual_yaw_floor: float | None = 0.3
    traction_probe: float | None = 1.25
    traction_floor: float = 0.1
    traction_recovery: float = 0.05
    fallback_derated: bool = True

    def __post_init__(self) -> None:
        def pos_or_none(v):
            return v is None or (isinstance(v, (int, float)) and math.isfinite(v) and v > 0)

        _check("pose_filter", self.pose_filter is None or isinstance(self.pose_filter, PoseFilterConfig),
               "a PoseFilterConfig or None", self.pose_filter)
        _check("monitor", isinstance(self.monitor, MonitorConfig), "a MonitorConfig", self.monitor)
        _check("excursion_stop", pos_or_none(self.excursion_stop), "None or a positive finite number of m",
               self.excursion_stop)
        _check("traction_probe", pos_or_none(self.traction_probe), "None or a positive finite number",
               self.traction_probe)
        _check("traction_floor", isinstance(self.traction_floor, (int, float)) and 0 < self.traction_floor <= 1,
               "in (0, 1]", self.traction_floor)
        tr = self.traction_recovery
        _check("traction_recovery", isinstance(tr, (int, float)) and math.isfinite(tr) and tr >= 0,
               "a finite number >= 0", tr)
        for name in ("derate_floor", "residual_floor", "residual_yaw_floor"):
            v = getattr(self, name)
            if v is None and name == "residual_yaw_floor":
                continue
            _check(name, isinstance(v, (int, float)) and 0 <= v <= 1, "in [0, 1]", v)
        rf = self.residual_free
        _check("residual_free", isinstance(rf, (int, float)) and math.isfinite(rf) and rf >= 0,
               "a finite number >= 0 m/s", rf)
        rs = self.residual_stop
        _check("residual_stop", rs is None or (isinstance(rs, (int, float)) and math.isfinite(rs) and rs > rf),
               f"None or a finite number above residual_free ({rf!r} m/s)", rs)


#: every adaptation off: the measured pose as it is, no derating, the model's rate bound.
NO_ADAPTATION = AdaptationConfig(
    latency_compensation=False, pose_filter=None, excursion_stop=None, residual_stop=None,
    residual_yaw_floor=None, traction_probe=None, fallback_derated=False,
)


class PlantAdaptation:
    """Adaptation of an MPC to its plant (see the module docstring), for one robot.

    Args:
        robot: the robot's nominal parameters (half track for the monitor).
        dt: [s] control period.
        v_max: [m/s] the MPC's resolved top speed (the derating's reference).
        w_max: [rad/s] the MPC's resolved top yaw rate.
        a_max: [m/s^2] the MPC's resolved speed rate bound (the traction limit's ceiling).
        lower, upper: (2,) [m/s, rad/s] input bounds every sent command is clipped to.
        config: settings.

    Attributes:
        config: settings.
        monitor: the :class:`~sanav_mj.control.monitor.ActuationMonitor` (identified delay,
            gains and tracking residual of the current episode).
        pose_filter: the :class:`~sanav_mj.control.monitor.PoseFilter`, or None.
    """

    def __init__(self, robot: RobotParams, dt: float, v_max: float, w_max: float, a_max: float,
                 lower: np.ndarray, upper: np.ndarray, config: AdaptationConfig = AdaptationConfig()):
        self.config = config
        self.dt = float(dt)
        self.v_max, self.w_max, self.a_max = float(v_max), float(w_max), float(a_max)
        self.lower = np.asarray(lower, dtype=float).copy()
        self.upper = np.asarray(upper, dtype=float).copy()
        self.half_track = 0.5 * float(robot.track)
        self.monitor = ActuationMonitor(config.monitor, half_track=self.half_track)
        self.pose_filter = PoseFilter(self.dt, config.pose_filter) if config.pose_filter is not None else None
        #: :class:`~sanav_mj.control.prediction.PredictionMonitor` derating the speed and yaw
        #: rate by the one-step prediction error (SA-MPC sets it in ``"discs"`` mode), or None.
        self.prediction = None
        self._x0: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the episode (monitor and filter)."""
        self.monitor.reset()
        if self.pose_filter is not None:
            self.pose_filter.reset()
        if self.prediction is not None:
            self.prediction.reset()
        self._x0 = None

    def update(self, velocity: np.ndarray | None) -> None:
        """Fold the measured body velocity (2,) [m/s, rad/s] (or None) into the monitor."""
        if velocity is not None:
            self.monitor.update(velocity)

    def filter(self, pose: np.ndarray, velocity: np.ndarray | None) -> np.ndarray:
        """(3,) [m, m, rad] the measured (finite) ``pose`` fused with ``velocity`` by the pose filter."""
        if self.pose_filter is None:
            return pose
        est = self.pose_filter.update(pose, velocity)
        if self.prediction is not None:
            self.prediction.observe_estimate(pose, est)
        return est

    def traction_accel(self, current: float) -> float:
        """[m/s^2] the next rate bound of the speed from the monitor's traction evidence.

        While the monitor sees the plant slip (``monitor.slipping``): ``traction_probe``
        times the largest speed change per period measured this episode (``peak_dv``, a
        lower bound of the grip) over ``dt``, not below ``traction_floor a_max``. Otherwise
        ``current`` recovers by the factor ``1 + traction_recovery`` per step up to
        ``a_max``; it is ``a_max`` as long as no slip was seen.
        """
        cfg = self.config
        a_max = self.a_max
        if cfg.traction_probe is None:
            return a_max
        if self.monitor.slipping:
            est = cfg.traction_probe * self.monitor.peak_dv / self.dt
            return float(min(a_max, max(est, cfg.traction_floor * a_max)))
        return float(min(a_max, current * (1.0 + cfg.traction_recovery)))

    def effective_state(self, pose: np.ndarray) -> np.ndarray:
        """(3,) state at the instant the next command takes effect, from the measured ``pose`` (3,).

        With latency compensation and an identified delay of ``d`` steps, the measured pose is
        rolled forward through the ``d`` commands already sent and not yet applied, scaled by
        the identified gains; else ``pose``.
        """
        from sanav_mj.control.unicycle import rollout_np

        if not self.config.latency_compensation or self.monitor.delay == 0:
            x0 = pose
        else:
            pending = self.monitor.pending() * self.monitor.gains
            x0 = rollout_np(pose, pending, self.dt)[-1]
        if self.prediction is not None:  # compared with what the last planned input predicted
            self.prediction.observe(x0)
            self._x0 = np.array(x0, dtype=float)
        return x0

    def send(self, u: np.ndarray) -> tuple[float, float]:
        """The command (v, w) [m/s, rad/s] sent for the planned input ``u`` (2,); recorded in the monitor."""
        cmd = np.asarray(u, dtype=float).copy()
        if self.prediction is not None:  # the model's state one period after the state planned from
            from sanav_mj.control.unicycle import rollout_np

            self.prediction.expect(None if self._x0 is None else rollout_np(self._x0, cmd[None], self.dt)[-1])
            self._x0 = None
        if self.config.gain_compensation:
            cmd = cmd / self.monitor.gains
        cmd = np.clip(np.nan_to_num(cmd), self.lower, self.upper)
        self.monitor.record(cmd)
        return float(cmd[0]), float(cmd[1])

    def speed_cap(self, excursion: float) -> float:
        """[m/s] speed bound for a position ``excursion`` [m] outside its constraint set:
        ``v_max max(derate_floor, 1 - excursion / excursion_stop)``."""
        stop = self.config.excursion_stop
        if stop is None or excursion <= 0:
            return self.v_max
        return self.v_max * max(self.config.derate_floor, 1.0 - excursion / stop)

    def residual_cap(self) -> float:
        """[m/s] speed bound from the monitor's velocity-tracking residual (see ``residual_stop``)."""
        cfg = self.config
        if cfg.residual_stop is None:
            return self.v_max
        r = float(np.hypot(self.monitor.residual[0], self.half_track * self.monitor.residual[1]))
        frac = min(max((r - cfg.residual_free) / (cfg.residual_stop - cfg.residual_free), 0.0), 1.0)
        return self.v_max * (1.0 - (1.0 - cfg.residual_floor) * frac)

    def residual_yaw_cap(self) -> float:
        """[rad/s] yaw-rate bound from the residual: the same fraction of ``w_max`` as
        :meth:`residual_cap` takes of ``v_max``, not below ``residual_yaw_floor w_max``."""
        cfg = self.config
        if cfg.residual_yaw_floor is None or cfg.residual_stop is None:
            return self.w_max
        frac = self.residual_cap() / self.v_max
        return self.w_max * max(frac, cfg.residual_yaw_floor)

    def prediction_cap(self) -> float:
        """[m/s] speed bound from the one-step prediction error (:attr:`prediction`; ``v_max`` without it)."""
        return self.v_max if self.prediction is None else self.v_max * self.prediction.fraction()

    def brake_response(self, w_max: float) -> tuple[float, np.ndarray | None]:
        """What the braking fallback's candidates use: the largest yaw rate [rad/s] they steer
        towards and the input gains (2,) they are rolled out with (None: the model's).

        ``(w_max, None)`` unless :attr:`prediction` tightens (SA-MPC's ``"discs"`` mode,
        :mod:`sanav_mj.control.prediction`); then the derated yaw-rate bound (residual and
        prediction derating) and the monitor's identified gains ``(g_v, g_w)``: what the plant
        will do rather than what the model assumes. Measured at the envelope's corner
        (docs/results.md, "Tight spaces"): the disc-centre excursions beyond 2 cm traced in the
        first tightened version came from braking steps steering at up to 2.6 rad/s while the
        derating asked for less, on a plant turning 22 % more than commanded."""
        if self.prediction is None or not self.prediction.config.tighten:
            return w_max, None
        return min(w_max, self.residual_yaw_cap(), self.prediction_yaw_cap()), self.monitor.gains.copy()

    def prediction_yaw_cap(self) -> float:
        """[rad/s] yaw-rate bound from the one-step prediction error (``w_max`` without it)."""
        return self.w_max if self.prediction is None else self.w_max * self.prediction.yaw_fraction()
