"""What every solver back-end of the tracking problem offers: settings, result, protocol."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class SolveResult:
    """Outcome of one solve.

    Attributes:
        z: (2N,) [m/s, rad/s] final iterate (inputs, row-major (N, 2)).
        y: (m,) multipliers of ``g`` at the final iterate.
        y_z: (2N,) multipliers of the variable bounds (IPOPT/SQP), or None.
        status: back-end status string.
        converged: the back-end reports convergence to its tolerances.
        iterations: inner iterations (PANOC) or NLP iterations.
        solver_ms: [ms] time reported by or measured around the back-end call.
    """

    z: np.ndarray
    y: np.ndarray
    y_z: np.ndarray | None
    status: str
    converged: bool
    iterations: int
    solver_ms: float


class Backend(Protocol):
    """A solver for a :class:`TrackingOCP` (built once, solved many times)."""

    name: str

    def solve(
        self,
        p: np.ndarray,
        z_lb: np.ndarray,
        z_ub: np.ndarray,
        g_lb: np.ndarray,
        g_ub: np.ndarray,
        z0: np.ndarray,
        y0: np.ndarray | None = None,
        y_z0: np.ndarray | None = None,
    ) -> SolveResult:
        """Solve with parameters ``p``, bounds and a warm start (shapes as in SolveResult)."""


@dataclass(frozen=True)
class SolverSettings:
    """Back-end independent solver settings.

    Attributes:
        tol: optimality tolerance (PANOC/PANTR: ALM inner stationarity epsilon; IPOPT: ``tol``).
        constraint_tol: allowed constraint violation [m for positions, m/s and rad/s for
            increments] (ALM delta; IPOPT ``constr_viol_tol``).
        max_iter: iteration limit (PANOC/PANTR: inner iterations per ALM pass; IPOPT: NLP
            iterations).
        max_outer_iter: ALM outer iterations (PANOC/PANTR only).
        budget_ms: [ms] optional wall-clock limit per solve, or None.
        lbfgs_memory: L-BFGS memory of PANOC.
        initial_penalty: ALM initial penalty (PANOC/PANTR only).
        initial_tolerance: ALM tolerance of the first inner solve (PANOC/PANTR only; the
            inner tolerance shrinks 10x per outer iteration down to ``tol``). A warm-started
            MPC problem needs no loose first pass: 1e-2 with an initial penalty of 100 cut
            PANOC's iterations by 10 % against 1 and 10 on the recorded SA-MPC sequence.
        input_scale: (2,) [m/s, rad/s] the compiled problems (PANOC/PANTR) optimise over
            ``u / input_scale``; a larger yaw-rate scale balances the curvature of the two
            inputs and cuts PANOC's iterations by about a quarter on the SA-MPC problem.
        position_scale: [1/m] the compiled problems see the position rows of ``g`` multiplied
            by this factor: their ALM penalty is ``position_scale**2`` times that of the
            other rows and their violation tolerance ``constraint_tol / position_scale`` [m],
            tighter. 3 cut ZeroFPR's iterations by 8 % on the recorded SA-MPC sequence and
            brought its first inputs closer to the tight optimum (4.9e-3 against 1.7e-2).
    """

    tol: float = 1e-4
    constraint_tol: float = 1e-4
    max_iter: int = 300
    max_outer_iter: int = 20
    budget_ms: float | None = None
    lbfgs_memory: int = 40
    initial_penalty: float = 100.0
    initial_tolerance: float = 1e-2
    input_scale: tuple[float, float] = (1.0, 3.0)
    position_scale: float = 3.0

    def __post_init__(self):
        for name in ("tol", "constraint_tol", "initial_penalty", "initial_tolerance", "position_scale"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"SolverSettings.{name} must be a positive finite number, got {value!r}")
        for name in ("max_iter", "max_outer_iter", "lbfgs_memory"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"SolverSettings.{name} must be an integer >= 1, got {value!r}")
        if self.budget_ms is not None and not (math.isfinite(self.budget_ms) and self.budget_ms > 0):
            raise ValueError(f"SolverSettings.budget_ms must be None or a positive number of ms, got {self.budget_ms!r}")
        scale = self.input_scale
        if len(scale) != 2 or not all(math.isfinite(v) and v > 0 for v in scale):
            raise ValueError(f"SolverSettings.input_scale must be two positive finite numbers, got {scale!r}")
