"""Merged safe rectangles and their connectivity graph (paper Sec. III-A/B, Algorithm 1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SafeAreas:
    """Axis-aligned safe rectangles (free space for the robot centre) and their adjacency.

    Attributes:
        rects: (R, 4) float [m] world-frame ``xmin, ymin, xmax, ymax`` of each safe area.
        edges: (E, 2) int, pairs ``i < j`` of areas sharing a boundary segment of positive length.
        weights: (E,) [m] distance between the two areas' centres.
        portals: (E, 2, 2) [m] the shared boundary segment of each edge, endpoints ``[[x0, y0], [x1, y1]]``.
    """

    rects: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    portals: np.ndarray
