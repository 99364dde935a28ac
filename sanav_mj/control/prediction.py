"""Derating by the one-step prediction error of the footprint (``"discs"`` SA-MPC).

The stage boxes constrain the *model's* prediction; under mismatch the true footprint leaves
them by what the model mispredicts. Measured at the robustness envelope's corner on the
BARN-like worlds (margin 0.02 m; docs/results.md "Tight spaces"): every collision and every
far excursion followed an approach at 1.1-1.4 m/s with the yaw rate weaving +-2 rad/s, where
a disc centre's true position one period ahead differed from the plan's by a median 3.8 cm
(90th percentile 7.9 cm; 10 periods ahead 18 / 38 cm), against about 1 mm nominally. The
plan was then no description of where the robot would go, the braking came too late, and
the footprint left its boxes by 3-7 cm.

:class:`PredictionMonitor` measures that error online: every step it compares the state the
command takes effect from (after the pose filter and the latency compensation) with what the
previous step's plan predicted for that instant, at the footprint's disc centres (the points
the boxes constrain), and keeps the largest error over a short window. The speed and
yaw-rate bounds are lowered by it, like the excursion and residual derating of
:mod:`sanav_mj.control.adaptation`: none up to ``free``, linear down to ``floor`` at ``stop``.
A plant the model does not predict is driven slowly, which shrinks both its stopping
distance and the error per period (the errors measured scale with the speed).

Measured (100 BARN-like worlds, seed 0, margin 0.02 m, then defaults ``free`` 0.008 m, ``stop``
0.03 m; ``stop`` is 0.02 m since h14safe0, see "The estimate's offset"): nominally the error stays below ``free`` and every run is identical to the run
without the derating (79 / 100); at the envelope corner the largest true excursion of a disc
centre outside every safe area fell from 13.0 to 2.6 cm, the smallest true clearance of the
footprint rose from 0.1 cm (one collision) to 3.6 cm, 82 / 100 reach the goal (77 before),
at a mean time of 17.4 s instead of 12.1 s. With ``free`` 0.01 / ``stop`` 0.06 the corner
still weaved at 1.3 m/s and a grown-chain run collided.

**Tightening by the prediction error** (``PredictionDerating.tighten``, on by default;
:func:`sanav_mj.control.stages.tighten_relax`, used by SA-MPC's ``"discs"`` mode). The same
error also sizes the constraints. For one disc centre let ``S_k`` be its stage box at stage k
(its chain member shrunk by ``box_margin``, at most a quarter of its width) and
``delta = min(e_hat + tighten_extra, tighten_max)`` the tightening, ``e_hat`` the largest
error measured over the window (:meth:`PredictionMonitor.tightening`). The rows of stages
1..N get ``T_k = shrink(S_k, delta)`` (again at most a quarter width per side). When the
measured centre lies outside ``T_0`` the boxes of stages 1..N are widened towards it as
before (:func:`~sanav_mj.control.stages.relax_boxes`: a plan may stay where the robot is),
but **never beyond** ``S_k`` while the robot moves; at rest (previous input below 0.02 m/s
and 0.05 rad/s: a unicycle cannot move sideways in one period) the widening follows the
measured centre as before. Nominally ``e_hat`` is about 1 mm, so every box loses about
3 mm per side; under the envelope's corner it reads 1-3 cm.

Why the excursion is then bounded. Let ``e`` be the *true* error of the next period: the
distance between where a disc centre will be when the next command takes effect and where
the applied plan's stage 1 puts it.

1. *No accumulation.* While the robot moves, every accepted plan keeps each disc centre of
   stages 1..N inside ``S_k`` (the capped widening cannot leave it), and the fallback
   follows a shifted plan only while its centres stay within ``box_margin`` of the
   untightened boxes, i.e. inside the safe areas. So one period after such a step the true
   centre lies within ``e`` of a safe area, whatever the excursion before: the uncapped
   relaxation let each period add its error to the last (``x_{k+1} <= x_k + e``; the plan
   followed the measured robot out), the cap does not.
2. *Usually none.* If the measured centre was inside ``T_0`` (no widening) and ``e <=
   delta``, the true centre one period later lies in ``S_1``: inside the safe area with
   ``box_margin`` to spare.
3. *No contact.* The map is inflated by the disc radius plus ``footprint_margin`` and a safe
   area holds only cells free of it, so a disc centre within ``footprint_margin`` of a safe
   area keeps its disc, and with it the footprint part it covers, clear. With 1., a step
   after an accepted or shifted plan cannot touch while ``e <= footprint_margin`` (``<=
   footprint_margin + box_margin`` where the box is at least ``4 box_margin`` wide).

**The estimate's offset** (``bias_window``, ``bias_weight``; measured 2026-11-24, branch
h14safe0). The boxes hold the *estimated* disc centres; the true ones are off by the pose
filter's error. Under pose noise the filter (:class:`~sanav_mj.control.monitor.PoseFilter`)
trusts the measured body velocity, and when the plant slips sideways (which that velocity
does not show) its estimate drifts from the truth: at the envelope's corner on barn_0010 by
6.7 cm within five periods of a 1.15 m/s turn, while the one-step error the monitor sees
(estimate against prediction, both in the drifting frame) read 2.7 cm; accepted plans held
the estimate in its boxes and the true front centre left every safe area by 7.5 cm. The
measurement itself is unbiased, so :attr:`PredictionMonitor.bias`, the norm of the mean of
``measured - estimate`` at the disc centres over the last ``bias_window`` steps, shows the
drift (white noise of std ``sigma`` averages to about ``1.25 sigma / sqrt(bias_window)``, 1.1
cm at the corner's 1.75 cm), and it is added to ``delta``: the boxes shrink by what the
estimate may be off. Without pose noise the filter passes the measurement through, the bias
is exactly 0 and nothing changes. Together with the stronger derating (``stop`` 0.02 m
instead of 0.03: a mispredicted plant is driven slower, which shortens the braking paths
below), with the stage boxes unshrunk (``MPCConfig.footprint_box_margin`` 0), measured on the
100 BARN-like worlds (docs/results.md, "Tight spaces"): nominal unchanged (95 / 100, the
error stays below ``free``), at the corner the largest true excursion of a disc centre
outside every safe area fell from 7.5 to 3.9 cm (<= the 0.04 m ``footprint_margin``; 89
instead of 91 / 100 reach the goal, 0 collisions, smallest true clearance 4.3 instead of 1.1
cm); on barn_0010 alone 7.5 cm before, 4.8 cm with the stronger derating only, 0 with both.
What remains at the corner (barn_0071, 3.9 cm on accepted steps) is the estimate's *noise*
(2 cm there), which the bias does not see, where the boxes are too narrow to shrink by
the whole ``delta`` (a quarter of the width per side at most).

What this assumes and does not cover, honestly: ``e`` is the true error, while the monitor
measures the *estimated* state (pose filter, latency compensation with the identified delay)
against the prediction, so the estimation error enters both ways (the bias term covers the
estimate's slow drift, not its noise); the window's maximum bounds the next period's error only if the error changes slowly (a turn that starts to slip
is seen one period late); between samples a disc centre leaves its chord by < 1 mm
(``tighten_extra`` covers it). **Braking steps are outside the argument**: the braking
fallback's path is not held to the boxes; it steers at most at the derated yaw rate and its
candidates are scored on the identified response
(:meth:`~sanav_mj.control.adaptation.PlantAdaptation.brake_response`), but a robot braking from speed ``v`` travels about
``v^2 / (2 a_max)`` on a model that mispredicts by ``e`` per period; only the derating's
lower speed limits that. Nor are the steps from rest: with the boxes unshrunk the largest
nominal excursion (2.8 cm, barn_0095) builds up in a loop of plans from rest and braking
steps, where the widening that follows the resting robot lets a plan slide along the
outside of its stage box (the centre lay 3.3 cm beyond the box but only 1 cm outside the
union of the safe areas) and the next, moving step finds no plan back in. The footprint margin is therefore
sized from the error measured under the envelope (docs/results.md, "Tight spaces": the
largest excursion of every run and where it came from), not guaranteed by this argument.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from sanav_mj.control.footprint import disc_centres


@dataclass(frozen=True)
class PredictionDerating:
    """Settings of :class:`PredictionMonitor`.

    Attributes:
        free: [m] one-step prediction error (largest over the window and the disc centres)
            below which nothing is derated.
        stop: [m] error at which the bounds reach ``floor`` (> ``free``).
        floor: fraction of ``v_max`` (and of ``w_max``, not below ``yaw_floor``) the derating
            never goes below, in (0, 1].
        yaw_floor: fraction of ``w_max`` the yaw-rate bound never goes below, in (0, 1].
        window: steps over which the largest error is kept (>= 1).
        tighten: shrink the disc rows' stage boxes by the error bound :meth:`PredictionMonitor.tightening`
            and cap their relaxation (:func:`sanav_mj.control.stages.tighten_relax`, "Tightening
            by the prediction error" in the module docstring); False: derating only.
        tighten_extra: [m] constant added to the measured error in the tightening (>= 0): what
            the error sampled once per period does not see, the disc centres' departure from
            their chord between samples (< 1 mm, :mod:`sanav_mj.control.footprint`) and one
            rasteriser-scale millimetre.
        tighten_max: [m] the tightening never exceeds this (> 0); each box is in any case
            shrunk by at most a quarter of its width (:func:`~sanav_mj.control.stages.shrink_box`).
        bias_window: steps over which the pose filter's offset from the measured pose is
            averaged for :attr:`PredictionMonitor.bias` (>= 1).
        bias_weight: weight (>= 0) of :attr:`PredictionMonitor.bias` in the tightening; 0: off.
    """

    free: float = 0.008
    stop: float = 0.02
    floor: float = 0.25
    yaw_floor: float = 0.3
    window: int = 20
    tighten: bool = True
    tighten_extra: float = 0.002
    tighten_max: float = 0.05
    bias_window: int = 4
    bias_weight: float = 1.0

    def __post_init__(self) -> None:
        ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                 for v in (self.free, self.stop, self.floor, self.yaw_floor))
        if not ok or not (0 <= self.free < self.stop):
            raise ValueError(f"PredictionDerating needs finite 0 <= free < stop [m], got free={self.free!r} "
                             f"stop={self.stop!r}")
        for name in ("floor", "yaw_floor"):
            v = getattr(self, name)
            if not 0 < v <= 1:
                raise ValueError(f"PredictionDerating.{name} must be in (0, 1], got {v!r}")
        if isinstance(self.window, bool) or not (isinstance(self.window, int) and self.window >= 1):
            raise ValueError(f"PredictionDerating.window must be an integer >= 1, got {self.window!r}")
        if not isinstance(self.tighten, bool):
            raise ValueError(f"PredictionDerating.tighten must be a bool, got {self.tighten!r}")
        te, tm = self.tighten_extra, self.tighten_max
        if not (isinstance(te, (int, float)) and not isinstance(te, bool) and math.isfinite(te) and te >= 0):
            raise ValueError(f"PredictionDerating.tighten_extra must be a finite number >= 0 m, got {te!r}")
        if not (isinstance(tm, (int, float)) and not isinstance(tm, bool) and math.isfinite(tm) and tm > 0):
            raise ValueError(f"PredictionDerating.tighten_max must be a positive finite number of m, got {tm!r}")
        bw, bg = self.bias_window, self.bias_weight
        if isinstance(bw, bool) or not (isinstance(bw, int) and bw >= 1):
            raise ValueError(f"PredictionDerating.bias_window must be an integer >= 1, got {bw!r}")
        if isinstance(bg, bool) or not (isinstance(bg, (int, float)) and math.isfinite(bg) and bg >= 0):
            raise ValueError(f"PredictionDerating.bias_weight must be a finite number >= 0, got {bg!r}")


class PredictionMonitor:
    """The largest recent one-step prediction error of the footprint's disc centres.

    Args:
        offsets: (D, 2) [m] disc centres in the body frame.
        config: settings.
    """

    def __init__(self, offsets: np.ndarray, config: PredictionDerating):
        self.offsets = np.asarray(offsets, dtype=float).reshape(-1, 2)
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the episode."""
        self._expected: np.ndarray | None = None
        self._errors: deque[float] = deque(maxlen=self.config.window)
        self._offsets: deque[np.ndarray] = deque(maxlen=self.config.bias_window)
        self._nonzero: deque[bool] = deque(maxlen=self.config.bias_window)  # per entry of _offsets

    def expect(self, state: np.ndarray | None) -> None:
        """The state (3,) [m, m, rad] the applied plan predicts for the next step's effective
        state (its stage 1), or None (no prediction: the next step measures nothing)."""
        self._expected = None if state is None else np.asarray(state, dtype=float).reshape(3).copy()

    def observe(self, state: np.ndarray) -> float:
        """Fold the effective state (3,) of this step in; returns the error [m] measured (the
        largest disc-centre distance to the prediction; 0 without a prediction)."""
        if self._expected is None:
            return 0.0
        a, b = disc_centres(np.vstack((np.asarray(state, dtype=float).reshape(1, 3), self._expected[None])),
                            self.offsets)
        e = float(np.max(np.hypot(*(a - b).T)))
        if math.isfinite(e):
            self._errors.append(e)
        self._expected = None
        return e

    def observe_estimate(self, measured: np.ndarray, estimate: np.ndarray) -> None:
        """Fold in this step's measured pose (3,) and the pose filter's estimate (3,) [m, m,
        rad]: their disc centres' offsets (D, 2) [m] ``measured - estimate`` enter :attr:`bias`."""
        m = np.asarray(measured, dtype=float).reshape(1, 3)
        e = np.asarray(estimate, dtype=float).reshape(1, 3)
        if m.tobytes() == e.tobytes() and np.all(np.isfinite(m)):
            # the filter passed the measurement through: the same centres, offsets exactly 0
            # (what a - b gives for equal finite a and b)
            self._offsets.append(np.zeros((len(self.offsets), 2)))
            self._nonzero.append(False)
            return
        a, b = disc_centres(np.vstack((m, e)), self.offsets)
        d = a - b
        if np.all(np.isfinite(d)):
            self._offsets.append(d)
            self._nonzero.append(bool(np.any(d != 0.0)))

    @property
    def bias(self) -> float:
        """[m] how far the pose filter's estimate sits from the measurement, systematically:
        the largest over the disc centres of the norm of the mean offset ``measured -
        estimate`` over the last ``bias_window`` steps (0 before any; exactly 0 while the
        filter passes the measurement through, e.g. without pose noise). White measurement
        noise of std ``sigma`` per axis averages to about ``1.25 sigma / sqrt(bias_window)``;
        an estimate that drifts from the truth (slip the measured body velocity does not
        show) by ``b`` adds about ``b``."""
        if not self._offsets or not any(self._nonzero):
            return 0.0  # (the mean of zero offsets: exactly 0)
        m = np.mean(np.asarray(self._offsets), axis=0)
        return float(np.max(np.hypot(*m.T)))

    @property
    def error(self) -> float:
        """[m] the largest error over the window (0 before any)."""
        return max(self._errors, default=0.0)

    def fraction(self) -> float:
        """Fraction of ``v_max`` the speed bound keeps: 1 up to ``free``, linear to ``floor`` at ``stop``."""
        c = self.config
        x = min(max((self.error - c.free) / (c.stop - c.free), 0.0), 1.0)
        return 1.0 - (1.0 - c.floor) * x

    def tightening(self) -> float:
        """[m] how much the disc rows' stage boxes are shrunk this step: ``min(error +
        tighten_extra + bias_weight bias, tighten_max)`` (:attr:`error` the largest measured
        one-step error over the window, :attr:`bias` the estimate's offset from the
        measurement), 0 when ``tighten`` is off."""
        c = self.config
        if not c.tighten:
            return 0.0
        b = c.bias_weight * self.bias if c.bias_weight > 0 else 0.0
        return min(self.error + c.tighten_extra + b, c.tighten_max)

    def yaw_fraction(self) -> float:
        """Fraction of ``w_max`` the yaw-rate bound keeps: :meth:`fraction`, not below ``yaw_floor``."""
        return max(self.fraction(), self.config.yaw_floor)
