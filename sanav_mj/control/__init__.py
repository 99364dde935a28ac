"""Controllers: the safe-area MPC of the paper and the baselines, all behind ``base.Controller``.

Modules, in the order of the data flow: ``base`` (Observation, Command, Controller),
``unicycle`` (model, CasADi + NumPy twins), ``problem`` (the tracking NLP), ``solver`` /
``backends`` / ``backend_alpaqa`` / ``backend_ipopt`` / ``sqp`` / ``codegen`` (its solvers,
one registry, compiled code and its cache), ``monitor`` + ``adaptation`` (the adaptation to
the plant), ``config`` (settings), ``tracking`` (the tracking-MPC core), ``stages`` +
``sa_mpc`` (SA-MPC), ``penalty_mpc``, ``dwa``, ``dqn``, ``spec`` + ``factory`` (which
controller, built once). This file only re-exports; ``SAMPC`` loads CasADi on first access.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sanav_mj.control.base import Command, Controller, Observation
from sanav_mj.control.config import MPCConfig, PenaltyConfig, TrackingConfig
from sanav_mj.control.spec import CONTROLLER_NAMES, ControllerSpec

if TYPE_CHECKING:  # pragma: no cover
    from sanav_mj.control.sa_mpc import SAMPC

__all__ = ["Command", "Controller", "Observation", "SAMPC", "MPCConfig", "TrackingConfig", "PenaltyConfig",
           "ControllerSpec", "CONTROLLER_NAMES"]


def __getattr__(name: str):
    if name == "SAMPC":
        from sanav_mj.control.sa_mpc import SAMPC

        return SAMPC
    raise AttributeError(f"module 'sanav_mj.control' has no attribute {name!r}")
