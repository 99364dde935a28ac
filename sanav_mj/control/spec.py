"""Which controller to run and with which settings: built once at the edge, passed on.

A :class:`ControllerSpec` names the controller (one of :data:`CONTROLLER_NAMES`, the one list
of names) and carries every configuration it may need. The CLI / Python API builds it once;
:func:`sanav_mj.control.factory.make_controller`, the planner's settings
(:func:`sanav_mj.eval.prepare.planner_config`) and the plots
(:func:`sanav_mj.eval.plots.run_reference`) all read the same object instead of rebuilding
defaults. Importing this module does not load CasADi.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from sanav_mj.control.config import MPCConfig, PenaltyConfig, TrackingConfig
from sanav_mj.control.dwa import DWAConfig

#: the controllers, by their command-line names.
CONTROLLER_NAMES = ("sa-mpc", "mpc", "dwa", "dqn")


@dataclass(frozen=True)
class ControllerSpec:
    """A controller and its settings.

    Attributes:
        name: one of :data:`CONTROLLER_NAMES`.
        sa_mpc: SA-MPC's settings (also what the planner's speed, yaw-rate and acceleration
            caps and period are matched to, whatever the controller).
        mpc: the penalty MPC's core settings (:class:`~sanav_mj.control.config.TrackingConfig`).
        penalty: the penalty MPC's own settings (:class:`~sanav_mj.control.config.PenaltyConfig`).
        dwa: the DWA's settings.
    """

    name: str = "sa-mpc"
    sa_mpc: MPCConfig = MPCConfig()
    mpc: TrackingConfig = TrackingConfig()
    penalty: PenaltyConfig = PenaltyConfig()
    dwa: DWAConfig = DWAConfig()

    def __post_init__(self) -> None:
        if self.name not in CONTROLLER_NAMES:
            raise ValueError(f"controller: expected one of {', '.join(CONTROLLER_NAMES)}, got {self.name!r}")
        if not isinstance(self.sa_mpc, MPCConfig):
            raise ValueError(f"ControllerSpec.sa_mpc must be an MPCConfig, got {type(self.sa_mpc).__name__}")
        if type(self.mpc) is not TrackingConfig:
            raise ValueError(f"ControllerSpec.mpc must be a TrackingConfig, got {type(self.mpc).__name__}")
        if not isinstance(self.penalty, PenaltyConfig):
            raise ValueError(f"ControllerSpec.penalty must be a PenaltyConfig, got {type(self.penalty).__name__}")
        if not isinstance(self.dwa, DWAConfig):
            raise ValueError(f"ControllerSpec.dwa must be a DWAConfig, got {type(self.dwa).__name__}")

    def with_solve_budget(self, budget_ms: float | None) -> ControllerSpec:
        """The same spec with both MPCs' solves cut off after ``budget_ms`` [ms] (None: unchanged)."""
        if budget_ms is None:
            return self
        return replace(self, sa_mpc=replace(self.sa_mpc, solve_budget_ms=budget_ms),
                       mpc=replace(self.mpc, solve_budget_ms=budget_ms))
