"""Controllers: the safe-area MPC of the paper and the baselines, all behind ``base.Controller``.

Modules: ``base`` (Observation, Command, Controller), ``unicycle`` (model, CasADi + NumPy
twins), ``ocp`` (the shared tracking NLP and its solver back-ends), ``sa_mpc`` (SA-MPC).
``SAMPC`` and ``MPCConfig`` are importable from here; they load CasADi on first access only,
so importing the package for another controller stays cheap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sanav_mj.control.base import Command, Controller, Observation

if TYPE_CHECKING:  # pragma: no cover
    from sanav_mj.control.sa_mpc import SAMPC, MPCConfig

__all__ = ["Command", "Controller", "Observation", "SAMPC", "MPCConfig"]


def __getattr__(name: str):
    if name in ("SAMPC", "MPCConfig"):
        from sanav_mj.control import sa_mpc

        return getattr(sa_mpc, name)
    raise AttributeError(f"module 'sanav_mj.control' has no attribute {name!r}")
