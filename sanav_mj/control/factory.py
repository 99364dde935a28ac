"""Build a controller by its command-line name, so every method runs in the same harness."""

from __future__ import annotations

from dataclasses import replace

from sanav_mj.control.base import Controller
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.reference import Plan
from sanav_mj.scene import Scenario

CONTROLLER_NAMES = ("sa-mpc", "mpc", "dwa", "dqn")


def make_controller(
    name: str,
    scenario: Scenario,
    grid: OccupancyGrid,
    areas: SafeAreas,
    plan: Plan,
    solve_budget_ms: float | None = None,
) -> Controller:
    """A fresh controller for one episode.

    Args:
        name: ``"sa-mpc"`` (the paper's method), ``"mpc"`` (obstacle-penalty MPC baseline),
            ``"dwa"`` (dynamic window) or ``"dqn"`` (the shipped DQN policy).
        scenario: the scenario (robot parameters, obstacles, goal).
        grid: the inflated occupancy grid (DWA's distance field).
        areas: the safe areas (SA-MPC).
        plan: the planned corridor and reference (SA-MPC).
        solve_budget_ms: [ms] optional wall-clock cut-off of the MPC solvers.
    """
    if name == "sa-mpc":
        from sanav_mj.control.sa_mpc import MPCConfig, SAMPC

        cfg = MPCConfig()
        if solve_budget_ms is not None:
            cfg = replace(cfg, solve_budget_ms=solve_budget_ms)
        return SAMPC(scenario.robot, areas, plan, cfg)
    if name == "mpc":
        from sanav_mj.control.penalty_mpc import PenaltyMPC
        from sanav_mj.control.sa_mpc import MPCConfig

        cfg = MPCConfig()
        if solve_budget_ms is not None:
            cfg = replace(cfg, solve_budget_ms=solve_budget_ms)
        return PenaltyMPC(scenario.robot, scenario.obstacles, grid.inflation, scenario.goal, cfg)
    if name == "dwa":
        from sanav_mj.control.dwa import DWA

        return DWA(scenario.robot, grid, scenario.goal)
    if name == "dqn":
        from sanav_mj.control.dqn import DQNController

        return DQNController.load_default(scenario.robot, scenario.goal)
    raise ValueError(f"controller: expected one of {', '.join(CONTROLLER_NAMES)}, got {name!r}")
