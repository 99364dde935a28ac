"""Build a controller from its :class:`~sanav_mj.control.spec.ControllerSpec`, so every method runs in the same harness."""

from __future__ import annotations

from sanav_mj.control.base import Controller
from sanav_mj.control.spec import CONTROLLER_NAMES, ControllerSpec
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.reference import Plan
from sanav_mj.scene import Scenario

__all__ = ["CONTROLLER_NAMES", "make_controller"]


def make_controller(
    spec: ControllerSpec | str,
    scenario: Scenario,
    grid: OccupancyGrid,
    areas: SafeAreas,
    plan: Plan,
    solve_budget_ms: float | None = None,
) -> Controller:
    """A fresh controller for one episode.

    Args:
        spec: the controller and its settings (a bare name means its default settings):
            ``"sa-mpc"`` (the paper's method), ``"mpc"`` (obstacle-penalty MPC baseline),
            ``"dwa"`` (dynamic window) or ``"dqn"`` (the shipped DQN policy).
        scenario: the scenario (robot parameters, obstacles, goal).
        grid: the inflated occupancy grid (DWA's distance field, the penalty's inflation).
        areas: the safe areas (SA-MPC).
        plan: the planned corridor and reference (SA-MPC).
        solve_budget_ms: [ms] optional wall-clock cut-off of the MPC solvers (the
            ``solve_budget_ms`` mismatch), applied to the spec's MPC settings.
    """
    if isinstance(spec, str):
        spec = ControllerSpec(spec)
    spec = spec.with_solve_budget(solve_budget_ms)
    if spec.name == "sa-mpc":
        from sanav_mj.control.sa_mpc import SAMPC

        fp = None
        if spec.sa_mpc.footprint == "discs":
            from sanav_mj.footprint import robot_footprint

            fp = robot_footprint(scenario.model)
        return SAMPC(scenario.robot, areas, plan, spec.sa_mpc, footprint=fp)
    if spec.name == "mpc":
        from sanav_mj.control.penalty_mpc import PenaltyMPC

        return PenaltyMPC(scenario.robot, scenario.obstacles, grid.inflation, scenario.goal, spec.mpc, spec.penalty)
    if spec.name == "dwa":
        from sanav_mj.control.dwa import DWA

        return DWA(scenario.robot, grid, scenario.goal, spec.dwa)
    from sanav_mj.control.dqn import DQNController

    return DQNController.load_default(scenario.robot, scenario.goal)
