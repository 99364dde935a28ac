"""CasADi ``nlpsol`` back-ends of the tracking problem: IPOPT (exact Hessian, MUMPS), the reference.

Needs no C compiler: CasADi evaluates the functions in its SX virtual machine.
"""

from __future__ import annotations

import time
from pathlib import Path

import casadi as cs
import numpy as np

from sanav_mj.control.problem import TrackingOCP
from sanav_mj.control.solver import SolveResult, SolverSettings


class _CasadiNlpBackend:
    """Shared code of the CasADi ``nlpsol`` back-ends."""

    name = "casadi"
    plugin = ""

    def _options(self, settings: SolverSettings) -> dict:
        raise NotImplementedError

    def __init__(self, ocp: TrackingOCP, settings: SolverSettings = SolverSettings(), cache_dir: Path | None = None):
        t0 = time.perf_counter()
        self.ocp = ocp
        self.settings = settings
        nlp = {"x": ocp.z, "p": ocp.p, "f": ocp.f, "g": ocp.g}
        self.solver = cs.nlpsol(f"sanav_{self.name}", self.plugin, nlp, self._options(settings))
        self.compiled = False
        self.library = None
        self.build_s = time.perf_counter() - t0

    def _converged(self, stats: dict) -> bool:
        return bool(stats.get("success", False))

    def solve(self, p, z_lb, z_ub, g_lb, g_ub, z0, y0=None, y_z0=None) -> SolveResult:
        args = dict(x0=z0, p=p, lbx=z_lb, ubx=z_ub, lbg=g_lb, ubg=g_ub)
        if y0 is not None:
            args["lam_g0"] = y0
        if y_z0 is not None:
            args["lam_x0"] = y_z0
        t0 = time.perf_counter()
        sol = self.solver(**args)
        ms = (time.perf_counter() - t0) * 1e3
        stats = self.solver.stats()
        return SolveResult(
            z=np.asarray(sol["x"]).ravel(),
            y=np.asarray(sol["lam_g"]).ravel(),
            y_z=np.asarray(sol["lam_x"]).ravel(),
            status=str(stats.get("return_status", "unknown")),
            converged=self._converged(stats),
            iterations=int(stats.get("iter_count", -1)),
            solver_ms=ms,
        )


class IpoptBackend(_CasadiNlpBackend):
    """IPOPT (exact Hessian, MUMPS) through CasADi: the reference solver."""

    name = "ipopt"
    plugin = "ipopt"

    def _options(self, settings: SolverSettings) -> dict:
        ipopt = {
            "print_level": 0,
            "sb": "yes",
            "tol": settings.tol,
            "constr_viol_tol": settings.constraint_tol,
            "max_iter": settings.max_iter,
            "warm_start_init_point": "yes",
            "mu_strategy": "adaptive",
        }
        if settings.budget_ms:
            ipopt["max_wall_time"] = settings.budget_ms / 1e3
        return {"ipopt": ipopt, "print_time": False}
