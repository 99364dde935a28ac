"""alpaqa's augmented Lagrangian solvers on the compiled tracking problem.

:class:`PanocBackend`: ALM with PANOC inner solver and L-BFGS directions (the paper's
solver); :class:`PantrBackend`: the same with PANTR (Newton trust-region directions from
Hessian-vector products); :class:`ZeroFprBackend`: the same with ZeroFPR (PANOC's sibling
from the same authors, L-BFGS directions). The CasADi functions and their gradients are
generated as C, compiled and cached on disk (:mod:`sanav_mj.control.codegen`).
"""

from __future__ import annotations

import time
from datetime import timedelta
from pathlib import Path

import casadi as cs
import numpy as np

from sanav_mj.control.codegen import compile_alpaqa_problem
from sanav_mj.control.problem import TrackingOCP
from sanav_mj.control.solver import SolveResult, SolverSettings


def _status_name(status) -> str:
    # ``.name`` of alpaqa's enum; ``str(enum)`` leaks a little memory on every call (measured
    # with scripts/endurance.py: about 30 B per solve).
    name = getattr(status, "name", None)
    return name if isinstance(name, str) else str(status).split(".")[-1]


class PanocBackend:
    """alpaqa's ALM with PANOC (L-BFGS directions) on the compiled problem: the paper's solver.

    The problem is compiled in scaled inputs ``u / input_scale`` (rate rows of ``g`` scaled
    alike, position rows multiplied by ``position_scale``); :meth:`solve` takes and returns
    unscaled quantities.

    Attributes:
        name: ``"panoc"``.
        library: path of the loaded shared library.
        compiled: True when this construction compiled the code (cache miss).
        build_s: [s] construction time (generation + compilation on a miss, loading otherwise).
    """

    name = "panoc"
    second_order = "no"

    def __init__(self, ocp: TrackingOCP, settings: SolverSettings = SolverSettings(), cache_dir: Path | None = None):
        import alpaqa

        t0 = time.perf_counter()
        self.ocp = ocp
        self.settings = settings
        n = ocp.horizon
        scale = np.asarray(settings.input_scale, dtype=float)
        self._zs = np.tile(scale, n)
        self._gs = np.concatenate((np.full(ocp.n_pos, 1.0 / settings.position_scale), np.tile(scale, n - 1)))
        zs = cs.SX.sym("zs", ocp.n_z)
        f_expr = cs.substitute(ocp.f, ocp.z, zs * cs.DM(self._zs))
        g_expr = cs.substitute(ocp.g, ocp.z, zs * cs.DM(self._zs)) / cs.DM(self._gs)
        f = cs.Function("f", [zs, ocp.p], [f_expr], ["x", "p"], ["f"])
        g = cs.Function("g", [zs, ocp.p], [g_expr], ["x", "p"], ["g"])
        self.library, self.compiled = compile_alpaqa_problem(f, g, self.second_order, cache_dir)
        self.problem = alpaqa.load_casadi_problem(str(self.library))
        self._max_time = timedelta(seconds=settings.budget_ms / 1e3) if settings.budget_ms else timedelta(minutes=5)
        alm = alpaqa.ALMParams(
            tolerance=settings.tol,
            dual_tolerance=settings.constraint_tol,
            initial_penalty=settings.initial_penalty,
            initial_tolerance=max(settings.initial_tolerance, settings.tol),
            max_iter=settings.max_outer_iter,
            max_time=self._max_time,
            print_interval=0,
        )
        self.solver = alpaqa.ALMSolver(alm, self._inner_solver(alpaqa, settings))
        self.build_s = time.perf_counter() - t0

    def _inner_solver(self, alpaqa, settings: SolverSettings):
        panoc = alpaqa.PANOCParams(max_iter=settings.max_iter, max_time=self._max_time, print_interval=0)
        return alpaqa.PANOCSolver(panoc, alpaqa.LBFGS.Params(memory=settings.lbfgs_memory))

    def solve(self, p, z_lb, z_ub, g_lb, g_ub, z0, y0=None, y_z0=None) -> SolveResult:
        prob = self.problem
        zs, gs = self._zs, self._gs
        prob.param = p
        prob.variable_bounds.lower = z_lb / zs
        prob.variable_bounds.upper = z_ub / zs
        prob.general_bounds.lower = g_lb / gs
        prob.general_bounds.upper = g_ub / gs
        y0 = np.zeros(self.ocp.n_g) if y0 is None else np.asarray(y0, dtype=float) * gs
        t0 = time.perf_counter()
        z, y, stats = self.solver(prob, np.asarray(z0, dtype=float) / zs, y0, asynchronous=False)
        ms = (time.perf_counter() - t0) * 1e3
        status = _status_name(stats["status"])
        return SolveResult(
            z=np.asarray(z) * zs,
            y=np.asarray(y) / gs,
            y_z=None,
            status=status,
            converged=status == "Converged",
            iterations=int(stats["inner"]["iterations"]),
            solver_ms=ms,
        )


class PantrBackend(PanocBackend):
    """alpaqa's ALM with PANTR (Newton trust-region directions from Hessian-vector products).

    Needs the second-order code (``psi_prod``): about twice the compile time of PANOC,
    6-8x fewer iterations and a little faster per solve on the SA-MPC problem.
    """

    name = "pantr"
    second_order = "psi_prod"

    def _inner_solver(self, alpaqa, settings: SolverSettings):
        params = alpaqa.PANTRParams(max_iter=settings.max_iter, max_time=self._max_time, print_interval=0)
        return alpaqa.PANTRSolver(params)


class ZeroFprBackend(PanocBackend):
    """alpaqa's ALM with ZeroFPR (L-BFGS directions; the line search on the forward-backward
    envelope along the quasi-Newton direction from the projected point, where PANOC blends
    the projected-gradient step and the direction). Same compiled code as PANOC.

    On the SA-MPC problem: about 15 % fewer iterations and less time per solve than PANOC.
    """

    name = "zerofpr"

    def _inner_solver(self, alpaqa, settings: SolverSettings):
        params = alpaqa.ZeroFPRParams(max_iter=settings.max_iter, max_time=self._max_time, print_interval=0)
        return alpaqa.ZeroFPRSolver(params, alpaqa.LBFGS.Params(memory=settings.lbfgs_memory))
