"""sanav-mj: quadtree safe-area MPC (SA-MPC) navigation of a differential-drive robot in MuJoCo.

The data flow is one-way (see README.md and docs/):

    scene -> mapping -> planning -> control -> sim -> eval / record / cli

The public Python API (:mod:`sanav_mj.api`, documented in docs/api.md) is re-exported here
and imported on first use, so ``import sanav_mj`` stays light (no MuJoCo, CasADi or NumPy
until a function is used). When gymnasium is installed, importing the package also registers
the training environment as ``"sanav_mj/Nav-v0"`` (:mod:`sanav_mj.envs`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sanav_mj.envs import register_envs as _register_envs

__version__ = "0.1.0"

__all__ = ["ControllerSpec", "Mismatch", "RunResult", "build_map", "load_scenario", "plan", "run_bench",
           "run_robustness", "run_scenario", "__version__"]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs
    from sanav_mj.api import (ControllerSpec, Mismatch, RunResult, build_map, load_scenario, plan, run_bench,
                              run_robustness, run_scenario)

_API = frozenset(__all__) - {"__version__"}


def __getattr__(name: str) -> Any:
    if name in _API:
        from sanav_mj import api

        return getattr(api, name)
    raise AttributeError(f"module 'sanav_mj' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | _API)


_register_envs()
