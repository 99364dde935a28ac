"""The unicycle tracking optimal-control problem and its solver back-ends.

One builder, :func:`build_tracking_ocp`, writes the nonlinear program shared by the MPC
controllers (SA-MPC and the obstacle-penalty MPC baseline): single shooting over the
inputs of the exact unicycle (:mod:`sanav_mj.control.unicycle`), the paper's tracking cost
and an optional extra position cost term supplied by the controller
(:class:`PositionCost`: the safe-area penalty J_SA for SA-MPC, obstacle polygons for the
baseline). Everything that changes between control steps is a *parameter* or a *bound*, so
the problem is built (and, for PANOC, compiled) once:

- decision variables ``z = (u_0, ..., u_{N-1})`` (2N,) [m/s, rad/s]; their box bounds
  (input bounds, the rate bound of ``u_0`` against the previously applied input, a terminal
  stop) are passed at every solve;
- parameters ``p`` (see :class:`ParamLayout`): measured state, previous input, reference
  states and inputs over the horizon, the diagonal weights and the position-cost data;
- general constraints ``g(z, p)`` with bounds passed at every solve:
  ``g = (p_1, ..., p_N, [position_constraints]; u_1 - u_0, ..., u_{N-1} - u_{N-2})``, i.e.
  the predicted positions (2N,) [m] (for the stage boxes) and the input increments
  (2(N-1),) [m/s, rad/s] (for the rate bounds).

Objective (paper eq. 10-11 plus the position term)::

    sum_{k=0}^{N-1} |x_k - xr_k|^2_Qx + |u_k - ur_k|^2_Qu + |u_k - u_{k-1}|^2_Qa
      + |x_N - xr_N|^2_QN + sum_{k=1}^{N} c(p_k)

with ``u_{-1}`` the previously applied input. The position term is summed over k = 1..N: at
k = 0 the position is the measured one, a constant.

Back-ends (same NLP, same parameters, same warm start):

- :class:`PanocBackend`: alpaqa's augmented Lagrangian method with PANOC inner solver and
  L-BFGS directions (the paper's solver); :class:`PantrBackend`: the same with PANTR
  (Newton trust-region directions from Hessian-vector products); :class:`ZeroFprBackend`:
  the same with ZeroFPR (PANOC's sibling from the same authors, L-BFGS directions). The CasADi functions
  and their gradients are generated as C, compiled with the system C compiler and cached
  on disk under a hash of the problem, so a second process only loads the shared library.
- :class:`IpoptBackend`: CasADi's IPOPT interface (exact Hessian, MUMPS), the reference.
"""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Protocol

import casadi as cs
import numpy as np

from sanav_mj.control.unicycle import rollout_cs

#: Environment variable overriding the on-disk cache of compiled problems.
CACHE_ENV = "SANAV_MJ_CACHE"


def default_cache_dir() -> Path:
    """Folder for compiled solver code: ``$SANAV_MJ_CACHE`` or ``~/.cache/sanav-mj``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "sanav-mj"


class PositionCost(Protocol):
    """An extra cost on each predicted position, with its own parameters.

    Attributes:
        key: short string identifying the structure of the expression (goes into the cache
            key of compiled code: change it whenever ``expr`` changes).
        n_params: number of parameters the term reads.
    """

    key: str
    n_params: int

    def expr(self, p, theta):
        """CasADi scalar cost of position ``p`` (2,) [m] given parameters ``theta`` (n_params,)."""


@dataclass(frozen=True)
class ParamLayout:
    """Where each block lives in the parameter vector (all slices into ``p``).

    Blocks, in order: ``x0`` (3,) [m, m, rad]; ``u_prev`` (2,) [m/s, rad/s]; ``x_ref``
    ((N+1)*3,) row-major (N+1, 3); ``u_ref`` (N*2,) row-major (N, 2); ``q_x`` (3,);
    ``q_u`` (2,); ``q_a`` (2,); ``q_n`` (3,); ``extra`` (n_extra,) position-cost data.
    """

    horizon: int
    n_extra: int

    @property
    def sizes(self) -> tuple[tuple[str, int], ...]:
        n = self.horizon
        return (
            ("x0", 3),
            ("u_prev", 2),
            ("x_ref", 3 * (n + 1)),
            ("u_ref", 2 * n),
            ("q_x", 3),
            ("q_u", 2),
            ("q_a", 2),
            ("q_n", 3),
            ("extra", self.n_extra),
        )

    @property
    def size(self) -> int:
        return sum(s for _, s in self.sizes)

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for name, s in self.sizes:
            out[name] = slice(i, i + s)
            i += s
        return out

    def pack(
        self,
        x0: np.ndarray,
        u_prev: np.ndarray,
        x_ref: np.ndarray,
        u_ref: np.ndarray,
        q_x: np.ndarray,
        q_u: np.ndarray,
        q_a: np.ndarray,
        q_n: np.ndarray,
        extra: np.ndarray | None = None,
    ) -> np.ndarray:
        """Concatenate the blocks (shapes as in the class docstring) into ``p`` (size,)."""
        parts = [x0, u_prev, x_ref, u_ref, q_x, q_u, q_a, q_n]
        if self.n_extra:
            parts.append(extra)
        return np.concatenate([np.asarray(a, dtype=float).ravel() for a in parts])


@dataclass
class TrackingOCP:
    """The symbolic single-shooting NLP ``min f(z, p) s.t. z in [zl, zu], g(z, p) in [gl, gu]``.

    Attributes:
        horizon: N, number of control intervals.
        dt: [s] step length.
        z: (2N,) SX decision variables (inputs, row-major (N, 2)).
        p: (P,) SX parameters laid out as ``layout``.
        f: scalar SX objective.
        g: (m,) SX constraints: positions (2N,) when ``position_constraints``, then input
            increments (2(N-1),).
        layout: parameter layout.
        position_constraints: whether ``g`` starts with the predicted positions.
        key: string that identifies the structure (used for caching compiled code).
    """

    horizon: int
    dt: float
    z: cs.SX
    p: cs.SX
    f: cs.SX
    g: cs.SX
    layout: ParamLayout
    position_constraints: bool
    key: str

    @property
    def n_z(self) -> int:
        return 2 * self.horizon

    @property
    def n_g(self) -> int:
        return int(self.g.numel())

    @property
    def n_pos(self) -> int:
        """Number of position-constraint rows at the start of ``g`` (2N or 0)."""
        return 2 * self.horizon if self.position_constraints else 0

    def functions(self) -> tuple[cs.Function, cs.Function]:
        """``f(z, p)`` and ``g(z, p)`` as CasADi functions (names ``f`` and ``g``)."""
        f = cs.Function("f", [self.z, self.p], [self.f], ["x", "p"], ["f"])
        g = cs.Function("g", [self.z, self.p], [self.g], ["x", "p"], ["g"])
        return f, g


def build_tracking_ocp(
    horizon: int,
    dt: float,
    position_cost: PositionCost | None = None,
    position_constraints: bool = True,
) -> TrackingOCP:
    """Build the tracking NLP described in the module docstring.

    Args:
        horizon: N >= 1, number of control intervals.
        dt: [s] > 0, step length (baked into the model).
        position_cost: optional extra cost on each predicted position p_1..p_N.
        position_constraints: include the predicted positions in ``g`` (for stage boxes).

    Returns:
        The symbolic problem.
    """
    if int(horizon) != horizon or horizon < 1:
        raise ValueError(f"horizon must be an integer >= 1, got {horizon!r}")
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    n = int(horizon)
    n_extra = position_cost.n_params if position_cost is not None else 0
    layout = ParamLayout(n, n_extra)
    z = cs.SX.sym("z", 2 * n)
    p = cs.SX.sym("p", layout.size)
    sl = layout.slices()
    x0 = p[sl["x0"]]
    u_prev = p[sl["u_prev"]]
    x_ref = cs.reshape(p[sl["x_ref"]], 3, n + 1)  # column k = reference state k
    u_ref = cs.reshape(p[sl["u_ref"]], 2, n)
    q_x, q_u, q_a, q_n = (p[sl[k]] for k in ("q_x", "q_u", "q_a", "q_n"))
    extra = p[sl["extra"]]

    us = [z[2 * k : 2 * k + 2] for k in range(n)]
    xs = rollout_cs(x0, us, dt)

    def wsq(e, q):
        return cs.dot(q, e * e)

    cost = 0
    u_last = u_prev
    for k in range(n):
        cost += wsq(xs[k] - x_ref[:, k], q_x)
        cost += wsq(us[k] - u_ref[:, k], q_u)
        cost += wsq(us[k] - u_last, q_a)
        u_last = us[k]
    cost += wsq(xs[n] - x_ref[:, n], q_n)
    if position_cost is not None:
        for k in range(1, n + 1):
            cost += position_cost.expr(xs[k][:2], extra)

    rows = []
    if position_constraints:
        rows += [xs[k][:2] for k in range(1, n + 1)]
    rows += [us[k] - us[k - 1] for k in range(1, n)]
    g = cs.vertcat(*rows) if rows else cs.SX(0, 1)
    key = f"track-N{n}-dt{dt!r}-pc{int(position_constraints)}-{position_cost.key if position_cost else 'none'}"
    return TrackingOCP(n, float(dt), z, p, cost, g, layout, position_constraints, key)


def shift_inputs(u: np.ndarray, start: int, horizon: int, rate_step: np.ndarray, u_last: np.ndarray) -> np.ndarray:
    """Warm start from a plan: ``u[start:]`` then braking towards (0, 0) at the rate limits.

    Args:
        u: (M, 2) [m/s, rad/s] plan.
        start: first input of ``u`` still to apply.
        horizon: N, rows of the result.
        rate_step: (2,) [m/s, rad/s] largest change of each input per step.
        u_last: (2,) input to brake from when nothing of ``u`` is left.

    Returns:
        (N, 2) inputs; every increment respects ``rate_step`` if ``u`` does.
    """
    rest = u[start:]
    out = np.empty((horizon, 2))
    m = min(len(rest), horizon)
    out[:m] = rest[:m]
    last = rest[m - 1] if m else np.asarray(u_last, dtype=float)
    for k in range(m, horizon):
        last = np.sign(last) * np.maximum(np.abs(last) - rate_step, 0.0)
        out[k] = last
    return out


def shift_multipliers(ocp: TrackingOCP, y: np.ndarray, shift_rates: bool = True) -> np.ndarray:
    """Multipliers of ``g`` (m,) shifted by one stage for the next problem's warm start.

    Positions move one stage earlier and repeat the last. Rates move likewise and end with 0
    when ``shift_rates``; otherwise they stay where they are: under a terminal stop the rate
    bounds that bind are mostly those of the braking at the end of every plan, which stays
    at the same stages of the horizon while the robot cruises (measured on the recorded
    SA-MPC sequence: 20 % fewer PANOC iterations than shifting them).
    """
    n = ocp.horizon
    parts = []
    if ocp.position_constraints:
        pos = y[: 2 * n].reshape(n, 2)
        parts.append(np.concatenate((pos[1:], pos[-1:])).ravel())
    rate = y[ocp.n_pos :].reshape(n - 1, 2)
    if shift_rates:
        parts.append(np.concatenate((rate[1:], np.zeros((1, 2)))).ravel())
    else:
        parts.append(rate.ravel())
    return np.concatenate(parts)


def shift_bound_multipliers(y_z: np.ndarray | None) -> np.ndarray | None:
    """Multipliers of the variable bounds (2N,) shifted by one stage (last stage 0), or None."""
    if y_z is None:
        return None
    return np.concatenate((y_z[2:], np.zeros(2)))


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


def _compiler() -> str:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return name
    raise RuntimeError("no C compiler found (set CC or install gcc) to compile the PANOC problem")


# -O3 for this CPU: 15-20 % faster code than -O1 on the SA-MPC problem (replay of the
# recorded sequence), about twice the compile time (6 -> 11 s for PANOC's code, once per
# machine thanks to the cache). -march=native makes the library specific to the processor,
# so the cache key includes it (see _cpu_id).
# -std=gnu89: CasADi's generated code then takes its own ``x < y ? x : y`` for fmin/fmax (its
# pre-C99 branch) instead of calls to libm's fmin/fmax, which GCC does not inline under
# IEEE rules; the SA-MPC functions hold about 1100 of them (J_SA's [.]_- and the ALM
# projections). Same results for finite numbers; 9-10 % less time per ZeroFPR solve on the
# recorded sequence. (-ffast-math gave 2-3 % more but drops IEEE semantics: not used.)
# -fno-semantic-interposition: CasADi's helpers (casadi_sq, casadi_fmin, ...) are global
# functions of the shared library, which -fPIC alone must call through the PLT and may not
# inline (another library could interpose them); with this flag GCC inlines them. 23 % less
# CPU per ZeroFPR solve on the recorded sequence (0.355 -> 0.274 ms, same iterates up to
# rounding: 36.9 instead of 37.1 iterations on average). -fno-math-errno: sqrt and friends
# do not set errno (results unchanged), 3 % more. Measured interleaved in one process.
_CFLAGS = (
    "-O3",
    "-march=native",
    "-std=gnu89",
    "-fPIC",
    "-fno-semantic-interposition",
    "-fno-math-errno",
    "-shared",
)


def _cpu_id() -> str:
    """The processor model and feature flags (Linux), part of the cache key of native code."""
    import platform

    parts = [platform.machine()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key = line.split(":", 1)[0].strip()
                if key in ("model name", "flags", "Features", "CPU part"):
                    parts.append(line.strip())
                if len(parts) >= 3:
                    break
    except OSError:
        parts.append(platform.processor())
    return "\n".join(parts)


def compile_alpaqa_problem(
    f: cs.Function, g: cs.Function, second_order: str = "no", cache_dir: Path | None = None
) -> tuple[Path, bool]:
    """Generate and compile an alpaqa problem from ``f(x, p)`` and ``g(x, p)``, or reuse the cache.

    The cache key hashes the serialised CasADi functions, the derivative level, the CasADi
    and alpaqa versions, the compiler flags and the processor, so any change of the problem structure
    (horizon, dt, cost terms, scaling) compiles anew. The library is written under a
    temporary name and renamed, so concurrent processes never load a half-written file.

    Args:
        f: objective, ``f(x (n,), p (P,)) -> (1,)``.
        g: constraints, ``g(x, p) -> (m,)``.
        second_order: alpaqa's derivative level (``"no"`` for PANOC, ``"psi_prod"`` for PANTR).
        cache_dir: folder of the cache (default :func:`default_cache_dir`).

    Returns:
        (path of the shared library, True when it was compiled by this call).
    """
    import alpaqa

    key = (f.serialize(), g.serialize(), second_order, cs.__version__, alpaqa.__version__, "cse")
    return cached_shared_library(
        "alpaqa", key, lambda folder: _generate_cse(f, g, second_order).generate(str(folder) + os.sep),
        "the alpaqa problem", cache_dir,
    )


def cached_shared_library(
    prefix: str,
    key: tuple[str, ...],
    generate,
    what: str,
    cache_dir: Path | None = None,
) -> tuple[Path, bool]:
    """Compile generated C into ``<cache>/<prefix>_<hash>.so`` once, or return the cached library.

    The hash covers ``key`` (whatever identifies the generated code: serialised functions,
    versions), the compiler flags and the processor. The library is written under a
    temporary name and renamed, so concurrent processes never load a half-written file.

    Args:
        prefix: file name prefix (``"alpaqa"``, ``"sqp"``).
        key: strings identifying the code.
        generate: ``generate(folder: Path) -> str`` writes the C source into ``folder`` and
            returns its path (called only on a cache miss).
        what: what is compiled, for the error message.
        cache_dir: folder of the cache (default :func:`default_cache_dir`).

    Returns:
        (path of the shared library, True when it was compiled by this call).

    Raises:
        RuntimeError: the compiler failed (its first 2000 characters of stderr).
    """
    h = hashlib.sha256()
    for part in (*key, " ".join(_CFLAGS), _cpu_id()):
        h.update(part.encode())
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = root / f"{prefix}_{h.hexdigest()[:20]}.so"
    if target.is_file():
        return target, False
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix="build_") as tmp:
        src = generate(Path(tmp))
        out = Path(tmp) / "lib.so"
        proc = subprocess.run([_compiler(), *_CFLAGS, src, "-o", str(out), "-lm"], capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"compiling {what} failed: {proc.stderr.strip()[:2000]}")
        os.replace(out, target)
    return target, True


def _generate_cse(f: cs.Function, g: cs.Function, second_order: str) -> cs.CodeGenerator:
    """alpaqa's generated problem functions (objective, constraints, the augmented Lagrangian
    with its gradient, ...), each rebuilt with CasADi's common-subexpression elimination.

    alpaqa's own ``generate_casadi_problem`` adds the functions as built, and the gradients
    repeat subexpressions of the forward pass (the cosines of the rollout, for instance): on
    the SA-MPC problem elimination shrinks ``psi_grad_psi`` from 8499 to 7785 instructions and
    ``psi`` from 3785 to 3191 (2-3 % less time per ZeroFPR solve). Names, inputs and outputs
    are alpaqa's, so its loader finds them.
    """
    try:
        from alpaqa.casadi_generator import _prepare_casadi_problem
    except ImportError:  # another alpaqa version: its public generator, without elimination
        from alpaqa.casadi_generator import generate_casadi_problem

        return generate_casadi_problem(f, g, second_order=second_order, name="sanav_problem")

    cg = cs.CodeGenerator("sanav_problem.c")
    for name, fn in _prepare_casadi_problem(f, g, second_order, cs.SX.sym).items():
        ins = fn.sx_in()
        outs = fn(*ins)
        outs = list(outs) if isinstance(outs, (list, tuple)) else [outs]
        cg.add(cs.Function(name, ins, outs, fn.name_in(), fn.name_out(), {"cse": True}))
    return cg


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


BACKENDS: dict[str, type] = {
    "panoc": PanocBackend,
    "pantr": PantrBackend,
    "zerofpr": ZeroFprBackend,
    "ipopt": IpoptBackend,
}


def _sqp_backend(ocp: TrackingOCP, settings: SolverSettings = SolverSettings(), cache_dir: Path | None = None) -> Backend:
    """:class:`sanav_mj.control.sqp.SqpBackend` (imported here: sqp.py imports this module)."""
    from sanav_mj.control.sqp import SqpBackend

    return SqpBackend(ocp, settings, cache_dir)


BACKENDS["sqp"] = _sqp_backend


def make_backend(name: str, ocp: TrackingOCP, settings: SolverSettings, cache_dir: Path | None = None) -> Backend:
    """Construct the back-end called ``name`` (one of :data:`BACKENDS`) for ``ocp``."""
    try:
        cls = BACKENDS[name]
    except KeyError:
        raise ValueError(f"solver must be one of {sorted(BACKENDS)}, got {name!r}") from None
    return cls(ocp, settings, cache_dir)
