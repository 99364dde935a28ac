"""C code generation of CasADi functions, compilation and the on-disk cache of shared libraries.

The compiled back-ends (alpaqa's PANOC/ZeroFPR/PANTR, the SQP) generate C from CasADi,
compile it with the system C compiler and cache the library under a hash of the problem, so
a second process only loads it. Without a C compiler :func:`find_compiler` raises
:class:`NoCompilerError`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from sanav_mj.native import CACHE_ENV, NoCompilerError, compile_cached, default_cache_dir, find_compiler

if TYPE_CHECKING:  # pragma: no cover
    import casadi as cs

__all__ = ["CACHE_ENV", "LOGGER", "NoCompilerError", "cached_shared_library", "compile_alpaqa_problem",
           "default_cache_dir", "find_compiler"]

#: name of the logger that reports compilation (one WARNING-level line per cache folder and
#: process, before the first compile): with no logging configured Python prints it on stderr.
LOGGER = "sanav_mj.control"

#: the first-compile notice (``%s``: the cache folder)
_NOTICE = "compiling the solver code once (about 10 s, then cached in %s)"


# -O3 for this CPU: 15-20 % faster code than -O1 on the SA-MPC problem (replay of the
# recorded sequence), about twice the compile time (6 -> 11 s for PANOC's code, once per
# machine thanks to the cache). -march=native makes the library specific to the processor,
# so the cache key includes it (see sanav_mj.native.cpu_id).
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
    import casadi as cs

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
    versions), the solver's compiler flags and the processor (see
    :func:`sanav_mj.native.library_path`). The library is written under a temporary name and
    renamed, so concurrent processes never load a half-written file.

    Args:
        prefix: file name prefix (``"alpaqa"``, ``"sqp"``).
        key: strings identifying the code.
        generate: ``generate(folder: Path) -> str`` writes the C source into ``folder`` and
            returns its path (called only on a cache miss).
        what: what is compiled, for the error message.
        cache_dir: folder of the cache (default :func:`default_cache_dir`).

    Returns:
        (path of the shared library, True when it was compiled by this call).

    On a miss the first compile into a folder is announced once per process on the
    :data:`LOGGER` logger (level WARNING): it takes about 10 s for the SA-MPC problem.

    Raises:
        NoCompilerError: a miss and no C compiler (see :func:`find_compiler`).
        CompileError: the compiler failed (its first 2000 characters of stderr; a RuntimeError).
    """
    return compile_cached(prefix, key, generate, _CFLAGS, what, cache_dir, notice=(LOGGER, _NOTICE))


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

    import casadi as cs

    cg = cs.CodeGenerator("sanav_problem.c")
    for name, fn in _prepare_casadi_problem(f, g, second_order, cs.SX.sym).items():
        ins = fn.sx_in()
        outs = fn(*ins)
        outs = list(outs) if isinstance(outs, (list, tuple)) else [outs]
        cg.add(cs.Function(name, ins, outs, fn.name_in(), fn.name_out(), {"cse": True}))
    return cg
