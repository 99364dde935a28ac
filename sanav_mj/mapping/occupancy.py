"""Occupancy grid rasterised exactly from the scenario's obstacle geoms, inflated by the robot."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OccupancyGrid:
    """A conservative, inflated occupancy grid.

    Cell ``(i, j)`` (row i along y, column j along x) covers
    ``[x0 + j*res, x0 + (j+1)*res] x [y0 + i*res, y0 + (i+1)*res]``.

    Attributes:
        occupied: (ny, nx) bool, True where any part of the cell meets an inflated obstacle
            or lies outside the workspace.
        resolution: [m] cell edge length.
        origin: (2,) [m] world x, y of the grid's lower-left corner.
        inflation: [m] obstacle inflation (footprint radius + margin).
        bounds: (4,) [m] workspace xmin, ymin, xmax, ymax.
    """

    occupied: np.ndarray
    resolution: float
    origin: np.ndarray
    inflation: float
    bounds: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx) cells."""
        return self.occupied.shape
