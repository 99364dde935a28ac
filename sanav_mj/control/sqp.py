"""Sequential quadratic programming back-end for the single-shooting tracking NLP.

:class:`SqpBackend` solves ``min f(z, p) s.t. zl <= z <= zu, gl <= g(z, p) <= gu`` of a
:class:`~sanav_mj.control.problem.TrackingOCP` by a line-search SQP method, the way real-time MPC
codes do (Newton-type iterations, each a small dense QP, warm-started):

- Evaluation: one generated, compiled C function returns everything an iteration needs
  at ``(z, p, y)``: ``f``, ``grad f`` (n,), ``g`` (m,), the Jacobian of ``g`` (m, n) and the
  Hessian of the Lagrangian ``f + y' g`` (n, n). It is compiled once with the flags of
  :mod:`sanav_mj.control.codegen` and cached on disk under a hash of the functions; it is called
  through ``ctypes`` on preallocated arrays (a few microseconds of Python per call).
- Hessian (``hessian``): ``"exact"`` (default), the Hessian of the Lagrangian
  ``f + y' g``; ``"objective"``, the Hessian of ``f`` alone; ``"gauss-newton"``,
  ``2 J_r' J_r`` of the tracking residuals (:func:`tracking_residuals`) plus the exact Hessian
  of the rest of ``f`` (the position cost). When the matrix is not positive definite
  (DAQP's factorisation fails or it reports non-convexity), it is first convexified along
  the expected active set, ``H + rho (J_A' J_A + I_B)`` (rows with nonzero multipliers,
  variables at a bound; ``rho`` from ``max |diag H|`` growing 10x up to 1000x): this leaves
  the QP's solution unchanged when that active set is the QP's, and at a constrained minimum
  it is the reduced Hessian that is positive definite, not necessarily the full one. Then,
  if still needed, ``delta I`` is added (``delta`` from a power-iteration estimate of the
  smallest eigenvalue, growing 4x). On the recorded SA-MPC sequence (2033 problems,
  warm-started): exact 1.79 SQP iterations per solve, 93 regularised QPs, every feasible
  problem converged; with ``delta I`` alone (from ``1e-4 max |diag H|``, 10x) 573
  regularised QPs, one line-search failure, and single solves of 155 and 300 (the limit)
  iterations in the kinematic closed loop of the built-in "complex" scenario, now 6 and 3;
  objective-only Hessian 2.10 iterations, Gauss-Newton 10.7 (the tracking residuals are not
  small when the reference runs ahead of what the constraints allow, so dropping their
  curvature costs Newton's convergence). Modifying the eigenvalues (``numpy.linalg.eigh``)
  wakes OpenBLAS's threads, which on this 2-core machine cost more than they saved (mean
  0.78 against 0.24 ms per solve; 0.22 ms with one thread).
- QP: ``min 0.5 d'Hd + grad' d`` s.t. the variable bounds and the linearised constraints
  (two-sided), solved by DAQP (a dual active-set method for small dense QPs) in one
  workspace kept across iterations and solves, so each QP starts from the previous QP's
  active set. When the linearised constraints are infeasible with the variable bounds, an
  elastic step is taken instead (the same QP with the linearised constraints soft, DAQP's
  quadratic slack penalty) with a line search on the l1 violation alone; when no step
  reduces the linearised violation, or after ``_MAX_ELASTIC`` consecutive elastic steps,
  the solve ends with status ``"Infeasible"`` (not converged; the controller's fallback
  takes over) and the least-violating iterate found.
- Globalisation: backtracking (halving, at most ``_MAX_BACKTRACK`` times) on the l1 merit
  ``f + mu * sum(violations)`` with Armijo constant 1e-4; ``mu`` is raised to
  ``1.1 * max |QP multiplier|`` (and never lowered within a solve). The full step is taken in
  the usual case. A failed line search ends the solve with ``"LineSearchFailed"``.
- Stopping: the KKT conditions at the current iterate with the current multipliers:
  stationarity ``|grad f + J' y + y_z|_inf <= tol`` (bound multipliers ``y_z`` chosen
  optimally: ``-r_i`` on a bound that is active to ``constraint_tol`` with the right sign,
  0 elsewhere), every violation ``<= constraint_tol`` and complementarity
  ``|y_i| * (distance of g_i to the bound its sign names) <= tol``; the warm start is
  tested first, so a solved problem costs one evaluation.

Multipliers follow CasADi/IPOPT's sign convention (Lagrangian ``f + y' g + y_z' z``: positive
at an upper bound, negative at a lower one), like the other back-ends.
"""

from __future__ import annotations

import ctypes
import math
import os
import time
from pathlib import Path

import casadi as cs
import numpy as np

from sanav_mj.control.codegen import cached_shared_library
from sanav_mj.control.problem import TrackingOCP
from sanav_mj.control.solver import SolveResult, SolverSettings
from sanav_mj.control.unicycle import rollout_cs

#: Infinite bounds are passed to the QP solver as this magnitude (DAQP_INF: no bound).
_BIG = 1e30
#: Most halvings of the step in one line search.
_MAX_BACKTRACK = 12
#: Hessian regularisation (inertia correction): the first ``delta`` relative to the largest
#: diagonal entry, its growth factor and the most attempts per QP.
_DELTA_MIN = 1e-4
_DELTA_GROWTH = 4.0
_MAX_REGULARISE = 12
#: Armijo constant of the line search.
_ARMIJO = 1e-4
#: DAQP's exit flags: 1 optimal, 2 soft optimal; -1 infeasible, -5 non-convex.
_DAQP_OK = (1, 2)
_DAQP_INFEASIBLE = -1
#: Largest convexification weight (relative to the largest diagonal entry of H) tried before
#: the shift.
_CONVEX_MAX = 1e3
#: DAQP iteration limit per QP (its default, 10000, let a cycling QP take a second; a regular
#: QP here takes 1-30 iterations).
_QP_ITER_LIMIT = 500
#: Weight of the squared violation in an elastic QP, relative to the largest diagonal entry of H.
_RHO_ELASTIC = 1e6
#: Most consecutive elastic steps (infeasible linearisations) before giving up.
_MAX_ELASTIC = 10


def _min_eigenvalue(h: np.ndarray, iterations: int = 40) -> float:
    """Estimate of the smallest eigenvalue of the symmetric ``h`` (n, n) by power iteration
    (first on ``h`` for the spectral radius ``r``, then on ``r I - h``). Matrix-vector
    products only: LAPACK's ``eigh`` wakes OpenBLAS's thread pool, which costs more than the
    whole solve on a busy 2-core machine. An estimate: the caller grows the shift further if
    the shifted matrix is still not positive definite."""
    n = h.shape[0]
    v = np.full(n, 1.0 / np.sqrt(n))
    radius = 0.0
    for _ in range(iterations // 2):
        w = h @ v
        radius = float(np.sqrt(w @ w))
        if radius == 0.0:
            return 0.0
        v = w / radius
    shifted = h - radius * np.eye(n)  # eigenvalues in [-2 r, 0]; the most negative is lambda_min - r
    v = np.full(n, 1.0 / np.sqrt(n)) + 1e-3 * np.arange(n) / n
    v /= np.sqrt(v @ v)
    mu = 0.0
    for _ in range(iterations):
        w = shifted @ v
        mu = float(v @ w)
        norm = float(np.sqrt(w @ w))
        if norm == 0.0:
            break
        v = w / norm
    return mu + radius


def tracking_residuals(ocp: TrackingOCP) -> cs.SX:
    """Residuals ``r(z, p)`` whose squared norm is the tracking part of ``ocp.f``.

    ``sqrt(q_x) * (x_k - xr_k)`` for k = 1..N-1, ``sqrt(q_n) * (x_N - xr_N)``,
    ``sqrt(q_u) * (u_k - ur_k)`` and ``sqrt(q_a) * (u_k - u_{k-1})`` for k = 0..N-1 (the
    objective of :func:`~sanav_mj.control.problem.build_tracking_ocp` without the position
    term; the k = 0 state term is a constant and left out).
    """
    n = ocp.horizon
    z, p = ocp.z, ocp.p
    sl = ocp.layout.slices()
    x_ref = cs.reshape(p[sl["x_ref"]], 3, n + 1)
    u_ref = cs.reshape(p[sl["u_ref"]], 2, n)
    w_x, w_u, w_a, w_n = (cs.sqrt(p[sl[k]]) for k in ("q_x", "q_u", "q_a", "q_n"))
    us = [z[2 * k : 2 * k + 2] for k in range(n)]
    xs = rollout_cs(p[sl["x0"]], us, ocp.dt)
    out, u_last = [], p[sl["u_prev"]]
    for k in range(n):
        if k > 0:
            out.append(w_x * (xs[k] - x_ref[:, k]))
        out.append(w_u * (us[k] - u_ref[:, k]))
        out.append(w_a * (us[k] - u_last))
        u_last = us[k]
    out.append(w_n * (xs[n] - x_ref[:, n]))
    return cs.vertcat(*out)


def sqp_functions(ocp: TrackingOCP, hessian: str = "exact") -> cs.Function:
    """The iteration function of ``ocp``.

    ``sqp_eval(z (n,), p (P,), y (m,), zl (n,), zu (n,), gl (m,), gu (m,), ctol (1,)) -> out``
    with bounds finite (infinite ones clipped by the caller). ``out`` is one dense vector:
    ``f`` (1), the KKT measures (4: stationarity ``|r|_inf`` with ``r = grad f + J' y`` zeroed
    on bounds active to ``ctol`` where the sign lets a bound multiplier cancel it, maximum
    violation, complementarity ``max |y_i| * distance to the bound its sign names``, l1
    violation), ``grad f`` (n), ``g`` (m), the Jacobian of ``g`` row-major (m*n), the Hessian
    of ``f + y' g`` (n*n, symmetric). Built with CasADi's common-subexpression elimination.
    """
    z, p = ocp.z, ocp.p
    n, m = ocp.n_z, ocp.n_g
    y = cs.SX.sym("y", m)
    zl, zu = cs.SX.sym("zl", n), cs.SX.sym("zu", n)
    gl, gu = cs.SX.sym("gl", m), cs.SX.sym("gu", m)
    ctol = cs.SX.sym("ctol")
    g = ocp.g
    grad = cs.gradient(ocp.f, z)
    jac = cs.jacobian(g, z)
    if hessian == "exact":
        hess = cs.hessian(ocp.f + cs.dot(y, g), z)[0]
    elif hessian == "objective":
        hess = cs.hessian(ocp.f, z)[0]
    elif hessian == "gauss-newton":
        res = tracking_residuals(ocp)
        jr = cs.jacobian(res, z)
        hess = 2 * cs.mtimes(jr.T, jr) + cs.hessian(ocp.f - cs.sumsqr(res), z)[0]
    else:
        raise ValueError(f"hessian must be 'exact', 'objective' or 'gauss-newton', got {hessian!r}")
    r = grad + cs.mtimes(jac.T, y)
    cancel = cs.logic_or(cs.logic_and(z - zl <= ctol, r > 0), cs.logic_and(zu - z <= ctol, r < 0))
    stat = cs.mmax(cs.fabs(cs.if_else(cancel, 0, r)))
    viol = cs.fmax(cs.fmax(cs.fmax(cs.mmax(gl - g), cs.mmax(g - gu)), cs.fmax(cs.mmax(zl - z), cs.mmax(z - zu))), 0)
    comp = cs.fmax(cs.mmax(cs.if_else(y > 0, y * (gu - g), -y * (g - gl))), 0)
    l1 = cs.sum1(cs.fmax(gl - g, 0) + cs.fmax(g - gu, 0)) + cs.sum1(cs.fmax(zl - z, 0) + cs.fmax(z - zu, 0))
    out = cs.vertcat(ocp.f, stat, viol, comp, l1, grad, g, cs.vec(cs.densify(jac).T), cs.vec(cs.densify(hess)))
    return cs.Function(
        "sqp_eval", [z, p, y, zl, zu, gl, gu, ctol], [cs.densify(out)],
        ["z", "p", "y", "zl", "zu", "gl", "gu", "ctol"], ["out"], {"cse": True},
    )  # fmt: skip


def compile_sqp_function(fn: cs.Function, cache_dir: Path | None = None) -> tuple[Path, bool]:
    """Generate C for ``fn`` and compile it into a shared library, or reuse the cached one.

    The cache key hashes the serialised function, the CasADi version, the compiler flags and
    the processor; the library is written under a temporary name and renamed, so concurrent
    processes never load a half-written file.

    Returns:
        (path of the shared library, True when it was compiled by this call).
    """
    def generate(folder: Path) -> str:
        cg = cs.CodeGenerator("sqp_eval.c", {"with_header": False})
        cg.add(fn)
        return cg.generate(str(folder) + os.sep)

    return cached_shared_library("sqp", (fn.serialize(), cs.__version__, "sqp1"), generate, "the SQP functions", cache_dir)


class _Compiled:
    """``ctypes`` caller of a generated CasADi function with preallocated inputs and output."""

    def __init__(self, library: Path, name: str, n_in: list[int], n_out: int):
        self._lib = ctypes.CDLL(str(library))
        fn = getattr(self._lib, name)
        work = getattr(self._lib, f"{name}_work")
        ll = ctypes.c_longlong
        sz = [ll(0) for _ in range(4)]
        work.argtypes = [ctypes.POINTER(ll)] * 4
        if work(*(ctypes.byref(s) for s in sz)) != 0:
            raise RuntimeError(f"{name}_work failed")
        sz_arg, sz_res, sz_iw, sz_w = (max(int(s.value), 1) for s in sz)
        self.inputs = [np.zeros(k) for k in n_in]
        self.out = np.zeros(n_out)
        self._iw = np.zeros(sz_iw, dtype=np.int64)
        self._w = np.zeros(sz_w)
        dp = ctypes.POINTER(ctypes.c_double)
        self._arg = (dp * sz_arg)(*[a.ctypes.data_as(dp) for a in self.inputs])
        self._res = (dp * sz_res)(self.out.ctypes.data_as(dp))
        fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
        fn.restype = ctypes.c_int
        self._fn = fn
        self._args = (
            ctypes.addressof(self._arg),
            ctypes.addressof(self._res),
            self._iw.ctypes.data,
            self._w.ctypes.data,
            0,
        )

    def __call__(self) -> np.ndarray:
        """Evaluate on the current contents of ``inputs``; returns ``out`` (overwritten)."""
        if self._fn(*self._args) != 0:
            raise RuntimeError("evaluation of the compiled SQP function failed")
        return self.out


class SqpBackend:
    """Line-search SQP with exact Hessian and DAQP QPs (see the module docstring).

    Attributes:
        name: ``"sqp"``.
        library: path of the loaded shared library.
        compiled: True when this construction compiled the code (cache miss).
        build_s: [s] construction time.
        qp_iterations: DAQP iterations of the last solve (diagnostic).
        regularised: Hessian regularisations of the last solve (diagnostic).
        backtracks: step halvings of the last solve (diagnostic).
        elastic: elastic steps of the last solve (diagnostic).
    """

    name = "sqp"

    def __init__(
        self,
        ocp: TrackingOCP,
        settings: SolverSettings | None = None,
        cache_dir: Path | None = None,
        hessian: str = "exact",
    ):
        import daqp

        settings = SolverSettings() if settings is None else settings
        t0 = time.perf_counter()
        self.ocp = ocp
        self.settings = settings
        n, m = ocp.n_z, ocp.n_g
        self._n, self._m = n, m
        self.library, self.compiled = compile_sqp_function(sqp_functions(ocp, hessian), cache_dir)
        n_out = 5 + n + m + m * n + n * n
        sizes = [n, ocp.layout.size, m, n, n, m, m, 1]
        self._eval = _Compiled(self.library, "sqp_eval", sizes, n_out)
        out = self._eval.out
        self._v_kkt = out[:5]  # f, stationarity, violation, complementarity, l1 violation
        self._v_grad = out[5 : 5 + n]
        self._v_g = out[5 + n : 5 + n + m]
        self._v_jac = out[5 + n + m : 5 + n + m + m * n].reshape(m, n)
        self._v_hess = out[5 + n + m + m * n :].reshape(n, n)
        self._in_z, self._in_p, self._in_y, self._in_zl, self._in_zu, self._in_gl, self._in_gu, ctol = self._eval.inputs
        ctol[0] = settings.constraint_tol
        self._H = np.zeros((n, n))
        self._A = np.zeros((m, n))
        self._bu = np.zeros(n + m)
        self._bl = np.zeros(n + m)
        self._grad = np.zeros(n)
        self._sense = np.zeros(n + m, dtype=np.intc)
        self._daqp = daqp
        self._qp = daqp.Model()
        self._qp_ready = False
        self.qp_iterations = 0
        self.regularised = 0
        self.backtracks = 0
        self.elastic = 0
        self.build_s = time.perf_counter() - t0

    # ------------------------------------------------------------------ helpers
    def _evaluate(self, z: np.ndarray, y: np.ndarray) -> None:
        self._in_z[:] = z
        self._in_y[:] = y
        self._eval()

    def _bound_multipliers(self, z: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(n,) multipliers of the variable bounds cancelling ``grad f + J' y`` where a bound
        active to ``constraint_tol`` allows it (sign convention of the module docstring)."""
        r = self._v_grad + y @ self._v_jac
        ctol = self.settings.constraint_tol
        lo = (z - self._in_zl <= ctol) & (r > 0)
        hi = (self._in_zu - z <= ctol) & (r < 0)
        return np.where(lo | hi, -r, 0.0)

    def _solve_qp(self, z, zl, zu, gl, gu, y):
        """Set up and solve the QP at the last evaluation: (exitflag, d, lam (n + m,)).

        The current multipliers ``y`` (m,) and the variables at a bound (to
        ``constraint_tol``) make the expected active set, used to convexify an indefinite
        Hessian."""
        n = self._n
        H, A, bu, bl = self._H, self._A, self._bu, self._bl
        H[:] = self._v_hess
        A[:] = self._v_jac
        np.subtract(zu, z, out=bu[:n])
        np.subtract(zl, z, out=bl[:n])
        np.subtract(gu, self._v_g, out=bu[n:])
        np.subtract(gl, self._v_g, out=bl[n:])
        self._grad[:] = self._v_grad
        delta, conv, rho, scale = 0.0, None, 0.0, 1.0
        for _ in range(_MAX_REGULARISE + 4):
            if not self._qp_ready:
                flag = self._qp.setup(H, self._grad, A, bu, bl, self._sense)[0]
                self._qp_ready = flag >= 0
                if self._qp_ready:
                    self._qp.settings = {"iter_limit": _QP_ITER_LIMIT}
            else:
                flag = self._qp.update(H=H, f=self._grad, A=A, bupper=bu, blower=bl)
                flag = flag[0] if isinstance(flag, tuple) else (0 if flag is None else int(flag))
            if flag >= 0:
                d, _, flag, info = self._qp.solve()
                self.qp_iterations += int(info["iterations"])
                if flag in _DAQP_OK or flag == _DAQP_INFEASIBLE:
                    return flag, np.array(d, dtype=float), np.array(info["lam"], dtype=float)  # copies: DAQP may reuse its memory
            # H is not positive definite (the factorisation failed or DAQP found the QP
            # non-convex). First convexify along the expected active set (the rows with
            # nonzero multipliers, the variables at a bound): H + rho (J_A' J_A + I_B), which
            # leaves the QP's solution unchanged if that active set is the QP's and is
            # positive definite for a large enough rho when the reduced Hessian is (the usual
            # case at a constrained minimum, where the full Hessian need not be). Then, if
            # still needed, add delta I (from an estimate of the smallest eigenvalue).
            if conv is None:
                ctol = self.settings.constraint_tol
                scale = max(1.0, float(np.max(np.abs(np.diag(self._v_hess)))))
                jac_a = self._v_jac[y != 0.0]
                conv = jac_a.T @ jac_a
                conv[np.diag_indices(n)] += (z - zl <= ctol) | (zu - z <= ctol)
                if not conv.any():  # no active set to convexify along: shift at once
                    rho = _CONVEX_MAX * scale
            if rho < _CONVEX_MAX * scale:
                rho = scale if rho == 0.0 else rho * 10.0
                np.add(self._v_hess, rho * conv, out=H)
                self.regularised += 1
                continue
            base = self._v_hess + rho * conv
            if delta == 0.0:
                delta = max(_DELTA_MIN * scale, -1.2 * _min_eigenvalue(base))
            else:
                delta *= _DELTA_GROWTH
            H[:] = base
            H[np.diag_indices(n)] += delta
            self.regularised += 1
        return flag, np.zeros(n), np.zeros(n + self._m)

    def _solve_elastic(self, z, zl, zu, gl, gu, rho: float):
        """The elastic version of the last QP, with its own DAQP call.

        Variables ``(d, t)``, ``t`` (m,) the violation allowed to each linearised row:
        ``min 0.5 d'Hd + grad'd + 0.5 rho |t|^2`` s.t. the variable bounds and
        ``gl - g - t <= J d <= gu - g + t``, ``t >= 0``; ``d = 0`` with ``t`` the violation
        is feasible; ``rho`` is relative to the largest diagonal entry of H. A quadratic
        penalty (least-squares violation, as an augmented Lagrangian or IPOPT's restoration
        phase lean towards) rather than the l1 one: on the ten infeasible problems of the
        recorded SA-MPC sequence the first inputs ended at most 0.28 m/s from IPOPT's (l1
        version ``rho sum(t)``: 0.77; an absolute weight 1e6: 0.73). (DAQP's own soft
        constraints, switched on through ``Model.update(sense=...)``, reported the soft QP
        infeasible and corrupted the heap: not used.) Returns (exitflag, d (n,), multipliers
        of g (m,)). Its own workspace: the main one keeps the active set of the regular QPs.
        """
        n, m = self._n, self._m
        H = np.zeros((n + m, n + m))
        H[:n, :n] = self._H  # as last factorised (regularised if it had to be)
        scale = max(1.0, float(np.max(np.abs(np.diag(self._H)))))
        H[np.arange(n, n + m), np.arange(n, n + m)] = rho * scale
        f = np.concatenate((self._v_grad, np.zeros(m)))
        jac = self._v_jac
        eye = np.eye(m)
        A = np.block([[jac, -eye], [jac, eye]])
        big = np.full(m, _BIG)
        bu = np.concatenate((zu - z, big, gu - self._v_g, big))
        bl = np.concatenate((zl - z, np.zeros(m), -big, gl - self._v_g))
        d, _, flag, info = self._daqp.solve(
            H, f, A, bu, bl, np.zeros(n + 3 * m, dtype=np.intc), iter_limit=_QP_ITER_LIMIT
        )
        self.qp_iterations += int(info["iterations"])
        lam = np.array(info["lam"], dtype=float)
        y = lam[n + m : n + 2 * m] + lam[n + 2 * m :]  # rows J d - t <= ., rows J d + t >= .
        return flag, np.array(d[:n], dtype=float), y

    # ------------------------------------------------------------------ solve
    def solve(self, p, z_lb, z_ub, g_lb, g_ub, z0, y0=None, y_z0=None) -> SolveResult:
        """Solve with parameters ``p`` (P,), bounds ``z_lb, z_ub`` (n,), ``g_lb, g_ub`` (m,), warm
        start ``z0`` (n,) [m/s, rad/s] and multipliers ``y0`` (m,) (``y_z0`` is not needed: the
        bound multipliers are recomputed). Returns a :class:`SolveResult`."""
        t0 = time.perf_counter()
        s = self.settings
        tol, ctol = s.tol, s.constraint_tol
        deadline = t0 + s.budget_ms / 1e3 if s.budget_ms else None
        n, m = self._n, self._m
        zl, zu, gl, gu = self._in_zl, self._in_zu, self._in_gl, self._in_gu
        for src, dst in ((z_lb, zl), (z_ub, zu), (g_lb, gl), (g_ub, gu)):  # ufuncs: np.clip's wrapper is slower
            np.maximum(np.minimum(src, _BIG, out=dst), -_BIG, out=dst)
        z = np.minimum(np.maximum(z0, zl), zu)
        y = np.zeros(m) if y0 is None else np.array(y0, dtype=float)
        if not math.isfinite(float(np.sum(z)) + float(np.sum(y))):
            z = np.minimum(np.maximum(np.nan_to_num(z), zl), zu)
            y = np.zeros(m)
        self._in_p[:] = p
        self.qp_iterations = self.regularised = self.backtracks = self.elastic = 0
        n_elastic = 0
        kkt = self._v_kkt
        mu = 0.0
        status, it = "MaxIter", 0
        self._evaluate(z, y)
        while True:
            f0, stat, viol, comp, v0 = kkt.tolist()
            if not np.isfinite(f0 + stat + viol + comp):
                status = "NotFinite"
                break
            if stat <= tol and viol <= ctol and comp <= tol:
                status = "Converged"
                break
            if it >= s.max_iter:
                status = "MaxIter"
                break
            if deadline is not None and time.perf_counter() > deadline:
                status = "MaxTime"
                break
            it += 1
            flag, d, lam = self._solve_qp(z, zl, zu, gl, gu, y)
            if flag == _DAQP_INFEASIBLE:
                if n_elastic >= _MAX_ELASTIC:
                    status = "Infeasible"
                    break
                flag, d, y_el = self._solve_elastic(z, zl, zu, gl, gu, _RHO_ELASTIC)
                if flag not in _DAQP_OK:
                    status = f"QPFailed({flag})"
                    break
                # the linearised violation after the step (the variable bounds hold)
                g_lin = self._v_g + self._v_jac @ d
                v_lin = float(np.sum(np.maximum(gl - g_lin, 0.0)) + np.sum(np.maximum(g_lin - gu, 0.0)))
                if v0 - v_lin <= 1e-9 * max(1.0, v0):
                    status = "Infeasible"  # no step reduces the violation of the linearisation
                    break
                n_elastic += 1
                self.elastic += 1
                y_new = y_el
                if not float(np.max(np.abs(y_new))) <= 10.0 * max(mu, 1.0):
                    y_new = y  # the penalty's price of a violated row, not the problem's multiplier
                alpha, accepted = 1.0, False
                for _ in range(_MAX_BACKTRACK):  # line search on the violation alone
                    z_try = np.minimum(np.maximum(z + alpha * d, zl), zu)  # rounding of the QP's bounds
                    self._evaluate(z_try, y_new)
                    if kkt[4] <= v0 - _ARMIJO * alpha * (v0 - v_lin):
                        accepted = True
                        break
                    alpha *= 0.5
                    self.backtracks += 1
                z = z_try
                y = y_new if alpha == 1.0 else y + alpha * (y_new - y)
                if alpha < 1.0:
                    self._evaluate(z, y)
                if not accepted:
                    status = "Infeasible"
                    break
                continue
            if flag not in _DAQP_OK:
                status = f"QPFailed({flag})"
                break
            n_elastic = 0
            y_new = lam[n:]
            mu = max(mu, 1.1 * float(np.max(np.abs(lam))))
            phi0 = f0 + mu * v0
            dphi = min(float(self._grad @ d) - mu * v0, 0.0)
            alpha, accepted = 1.0, False
            for _ in range(_MAX_BACKTRACK):
                z_try = np.minimum(np.maximum(z + alpha * d, zl), zu)  # rounding of the QP's bounds
                self._evaluate(z_try, y_new)
                if kkt[0] + mu * kkt[4] <= phi0 + _ARMIJO * alpha * dphi:
                    accepted = True
                    break
                alpha *= 0.5
                self.backtracks += 1
            z = z_try
            if alpha < 1.0:  # the iterate's multipliers are the blend; evaluate with them
                y = y + alpha * (y_new - y)
                self._evaluate(z, y)
            else:
                y = y_new
            if not accepted:
                status = "LineSearchFailed"
                break
        y_z = self._bound_multipliers(z, y)
        ms = (time.perf_counter() - t0) * 1e3
        return SolveResult(
            z=z.copy(),
            y=y,
            y_z=y_z,
            status=status,
            converged=status == "Converged",
            iterations=it,
            solver_ms=ms,
        )
