"""The interface every controller (SA-MPC, penalty MPC, DWA, DQN) offers the runner."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class Observation:
    """What a controller sees at one control step.

    Attributes:
        t: [s] simulation time.
        pose: (3,) [m, m, rad] measured x, y, yaw (possibly noisy).
        velocity: (2,) [m/s, rad/s] measured body forward speed v and yaw rate w.
        ranges: (n_rays,) [m] range readings (only filled when the controller asks for them
            through ``needs_ranges``), else None.
        scan: the latest 2-D lidar scan (an object with ``ranges`` (B,) [m], ``hit`` (B,)
            bool and ``angles`` (B,) [rad] relative to the robot heading) when the run senses
            with its lidar and a scan was taken this step, else None.
    """

    t: float
    pose: np.ndarray
    velocity: np.ndarray
    ranges: np.ndarray | None = None
    scan: Any = None


@dataclass(frozen=True)
class Command:
    """One control decision.

    Attributes:
        v: [m/s] commanded forward speed (always finite).
        w: [rad/s] commanded yaw rate (always finite).
        solve_ms: [ms] wall time of the optimisation / decision, including the Python call.
        status: solver status string (``"ok"``, ``"fallback_shift"``, ``"fallback_stop"``, ...).
        ok: False when the solver failed and a fallback produced this command.
        predicted: (N+1, 3) [m, m, rad] predicted states, or None.
        rect_ids: (N+1,) int safe-area index assigned to each predicted state, or None.
        margins: (N+1,) [m] smallest constraint slack of each predicted position, or None.
    """

    v: float
    w: float
    solve_ms: float
    status: str = "ok"
    ok: bool = True
    predicted: np.ndarray | None = field(default=None, repr=False)
    rect_ids: np.ndarray | None = field(default=None, repr=False)
    margins: np.ndarray | None = field(default=None, repr=False)


class Controller(Protocol):
    """A feedback controller producing (v, w) at a fixed period ``dt``."""

    name: str
    dt: float
    needs_ranges: bool

    def reset(self, pose: np.ndarray) -> None:
        """Prepare for a new episode starting at ``pose`` (3,) [m, m, rad]."""

    def step(self, obs: Observation) -> Command:
        """Return the command for the next control period."""
