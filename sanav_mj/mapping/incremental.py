"""Safe areas kept up to date cell change by cell change instead of rebuilt (paper: future work).

Structure. The grid is cut into aligned tiles of ``tile x tile`` cells (a power of two);
each tile holds the quadtree of its cells, i.e. the subtree of the full quadtree
(:func:`sanav_mj.mapping.quadtree.build_quadtree`) rooted at that aligned block. Leaves at or
below tile size are therefore exactly the full quadtree's; a free block larger than a tile
is simply split into tiles. So the free *coverage* (the cells in free leaves, including the
conservative "mixed node at the minimum size is occupied" rule) is identical to a rebuild's.

State kept between updates:

* a count pyramid of occupied cells over aligned blocks up to tile size (updated by
  ``+-1`` along each changed cell's ancestors);
* the merged safe rectangles, stored in slots (``boxes[slot]`` in cells, ``alive[slot]``);
* the graph edges as slot pairs.

Update for a set of changed cells:

1. the pyramid counts of their ancestors (up to tile size) are updated; the tiles holding
   them are *dirty*;
2. every rectangle meeting a dirty tile is removed; its parts in clean tiles (the rectangle
   cut along tile lines) are kept as pieces;
3. the free quadtree leaves of the dirty tiles are found from the pyramid (level by level,
   all dirty tiles at once);
4. pieces and new leaves are merged with :func:`sanav_mj.mapping.safe_areas.merge_rects`
   (the paper's full-edge merge) and take the freed slots;
5. edges of removed rectangles are dropped; the new rectangles' neighbours are found among
   the rectangles near them by matching sides on one grid line whose spans overlap by a
   positive length (never a corner only): exactly the touching pairs.

Work per update grows with the dirty tiles and the rectangles meeting them, not the grid.

What differs from a rebuild: the rectangles. Merging is local to the removed rectangles,
so a new rectangle may share a full edge with an untouched one that a global merge would
have joined; coverage, disjointness, freeness and the graph (the exact touching pairs) are
the same properties a rebuild has (tested against one on seeded random update sequences).
"""

from __future__ import annotations

import numpy as np

from sanav_mj.mapping import area_kernel
from sanav_mj.mapping.occupancy import OccupancyGrid
from sanav_mj.mapping.safe_areas import SafeAreas, merge_rects


def _check_tile(tile: int, min_cell: int) -> tuple[int, int]:
    if isinstance(tile, bool) or not isinstance(tile, (int, np.integer)) or tile < 1 or tile & (tile - 1):
        raise ValueError(f"tile must be a power of two >= 1 [cells], got {tile!r}")
    if isinstance(min_cell, bool) or not isinstance(min_cell, (int, np.integer)) or min_cell < 1:
        raise ValueError(f"min_cell must be an integer >= 1 [cells], got {min_cell!r}")
    leaf = 1 << (int(min_cell) - 1).bit_length()
    if tile < leaf:
        raise ValueError(f"tile ({tile}) must be at least the smallest quadtree leaf "
                         f"2^ceil(log2(min_cell)) = {leaf} [cells]")
    return int(tile), int(min_cell)


class IncrementalSafeAreas:
    """Merged safe rectangles and their graph over a changing occupancy grid.

    Args:
        grid: the initial grid (``occupied`` True where the robot centre may not be, e.g.
            :meth:`sanav_mj.mapping.live_grid.LiveGrid.safe_grid`). Its ``occupied`` array
            is copied.
        min_cell: [cells] quadtree minimum node size, as :func:`~sanav_mj.mapping.quadtree.build_quadtree`.
        tile: [cells] tile edge, a power of two >= the smallest leaf (default 32).

    Attributes:
        occupied: (ny, nx) bool, the grid as of the last update (do not modify).
        boxes: (cap, 4) int64 slot storage of cell boxes ``[i0, j0, i1, j1)``; valid where ``alive``.
        alive: (cap,) bool.
        edges: (E, 2) int64 slot pairs ``a < b`` of touching rectangles.
    """

    def __init__(self, grid: OccupancyGrid, min_cell: int = 1, tile: int = 32) -> None:
        occ = np.asarray(grid.occupied)
        if occ.ndim != 2 or occ.dtype != bool or occ.size == 0:
            raise ValueError(f"grid.occupied must be a non-empty (ny, nx) bool array, got {occ.dtype} {occ.shape}")
        self.tile, self.min_cell = _check_tile(tile, min_cell)
        self.origin = np.asarray(grid.origin, dtype=float).copy()
        self.resolution = float(grid.resolution)
        ny, nx = occ.shape
        self.shape = (ny, nx)
        t = self.tile
        self._lt = t.bit_length() - 1
        self._nty, self._ntx = -(-ny // t), -(-nx // t)
        # level 0 padded to whole tiles with free ("don't care") cells, as the quadtree pads
        lvl0 = np.zeros((self._nty * t, self._ntx * t), dtype=np.int32)
        lvl0[:ny, :nx] = occ
        self._levels = [lvl0]
        for _ in range(self._lt):
            p = self._levels[-1]
            self._levels.append(p[0::2, 0::2] + p[1::2, 0::2] + p[0::2, 1::2] + p[1::2, 1::2])
        self.occupied = occ.copy()
        self._use_kernel = True  # the compiled loops when available (False: NumPy, the reference)
        self._pyr = area_kernel.Pyramid(self._levels)
        self._link_scratch: dict = {}  # work arrays of area_kernel.link_edges
        self.boxes = np.zeros((0, 4), dtype=np.int64)
        self.alive = np.zeros(0, dtype=bool)
        self.edges = np.zeros((0, 2), dtype=np.int64)
        self._free_slots: list[int] = []
        all_tiles = np.arange(self._nty * self._ntx)
        self._rebuild_tiles(all_tiles, np.zeros(0, dtype=np.int64))

    # ------------------------------------------------------------------ public

    def update(self, occupied: np.ndarray, changed) -> int:
        """Bring the safe areas in line with ``occupied``, of which only ``changed`` cells changed.

        Args:
            occupied: (ny, nx) bool, the new grid (only the ``changed`` cells are read).
            changed: (K,) int flat indices ``i * nx + j`` of cells that may have changed
                (cells listed whose value did not change are ignored; duplicates allowed).

        Returns:
            Number of dirty tiles that were recomputed (0: nothing changed).
        """
        occ = np.asarray(occupied)
        if occ.shape != self.shape or occ.dtype != bool:
            raise ValueError(f"occupied must be a {self.shape} bool array, got {occ.dtype} {occ.shape}")
        cells = self._check_cells(changed)
        return self.update_cells(cells, occ.reshape(-1)[cells])

    def update_cells(self, cells, values) -> int:
        """As :meth:`update`, given the new values of the listed cells only.

        Args:
            cells: (K,) int flat indices ``i * nx + j``.
            values: (K,) bool new occupancy of those cells (for a duplicated cell, all its
                entries must agree).

        Returns:
            Number of dirty tiles that were recomputed (0: nothing changed).
        """
        cells = self._check_cells(cells)
        new = np.asarray(values, dtype=bool).reshape(-1)
        if new.shape != cells.shape:
            raise ValueError(f"values must have one entry per cell ({cells.size}), got {new.size}")
        ny, nx = self.shape
        if self._use_kernel:  # compiled: a handful of calls instead of about a hundred
            dirty = np.zeros((self._nty, self._ntx), dtype=bool)
            tiles = area_kernel.apply_cells(self._pyr, cells, new, self.occupied, nx, self._ntx, dirty)
            if tiles is not None:
                if tiles.size:
                    removed = area_kernel.slots_meeting(self.alive, self.boxes, self.tile, dirty)
                    self._rebuild_tiles(tiles, removed, dirty)
                return int(tiles.size)
        mine = self.occupied.reshape(-1)
        diff = new != mine[cells]
        cells, new = cells[diff], new[diff]
        cells, first = np.unique(cells, return_index=True)
        new = new[first]
        if not cells.size:
            return 0
        mine[cells] = new
        delta = np.where(new, 1, -1).astype(np.int32)
        i, j = np.divmod(cells, nx)
        if not (self._use_kernel and area_kernel.pyramid_add(self._pyr, cells, delta, nx)):
            for d, lvl in enumerate(self._levels):
                np.add.at(lvl, (i >> d, j >> d), delta)
        tiles = np.unique((i >> self._lt) * self._ntx + (j >> self._lt))
        self._rebuild_tiles(tiles, self._slots_meeting(tiles))
        return int(tiles.size)

    def _check_cells(self, cells) -> np.ndarray:
        ny, nx = self.shape
        c = np.asarray(cells).reshape(-1)
        if c.size and not np.issubdtype(c.dtype, np.integer):
            raise ValueError(f"changed cells must be integer flat indices, got dtype {c.dtype}")
        c = c.astype(np.int64, copy=False)
        if c.size and (c.min() < 0 or c.max() >= ny * nx):
            raise ValueError(f"changed cells must be flat indices in [0, {ny * nx}), got {c.min()}..{c.max()}")
        return c

    def safe_areas(self) -> tuple[np.ndarray, SafeAreas]:
        """The current rectangles and graph in compact form.

        Returns:
            boxes: (R, 4) int64 cell boxes ``[i0, j0, i1, j1)`` sorted by ``(i0, j0)``.
            areas: :class:`~sanav_mj.mapping.safe_areas.SafeAreas` over those boxes (world
                metres; edges sorted; weights and portals as
                :func:`~sanav_mj.mapping.safe_areas.connectivity` computes them).
        """
        base = max(self.shape) + 1
        if self._use_kernel:
            got = area_kernel.snapshot(self.alive, self.boxes, self.edges, base, self.origin, self.resolution)
            if got is not None:
                b, rects, e, weights, portals = got
                return b, SafeAreas(rects=rects, edges=e, weights=weights, portals=portals)
        slots = np.flatnonzero(self.alive)
        b = self.boxes[slots]
        order = np.argsort(b[:, 0] * base + b[:, 1])
        slots, b = slots[order], b[order]
        index = np.full(len(self.alive), -1, dtype=np.int64)
        index[slots] = np.arange(len(slots))
        e = index[self.edges]
        e = np.sort(e, axis=1)
        e = e[np.argsort(e[:, 0] * max(len(slots), 1) + e[:, 1])]
        h = self.resolution
        ox, oy = self.origin
        rects = np.stack([ox + h * b[:, 1], oy + h * b[:, 0], ox + h * b[:, 3], oy + h * b[:, 2]], axis=1).astype(float)
        centre = 0.5 * (rects[:, :2] + rects[:, 2:])
        weights = np.linalg.norm(centre[e[:, 0]] - centre[e[:, 1]], axis=1)
        ba, bb = b[e[:, 0]], b[e[:, 1]]
        side = (ba[:, 3] == bb[:, 1]) | (bb[:, 3] == ba[:, 1])  # side by side along x
        portals = np.empty((len(e), 2, 2))
        xline = np.where(ba[:, 3] == bb[:, 1], ba[:, 3], bb[:, 3])
        yline = np.where(ba[:, 2] == bb[:, 0], ba[:, 2], bb[:, 2])
        lo_i, hi_i = np.maximum(ba[:, 0], bb[:, 0]), np.minimum(ba[:, 2], bb[:, 2])
        lo_j, hi_j = np.maximum(ba[:, 1], bb[:, 1]), np.minimum(ba[:, 3], bb[:, 3])
        portals[:, 0, 0] = ox + h * np.where(side, xline, lo_j)
        portals[:, 1, 0] = ox + h * np.where(side, xline, hi_j)
        portals[:, 0, 1] = oy + h * np.where(side, lo_i, yline)
        portals[:, 1, 1] = oy + h * np.where(side, hi_i, yline)
        return b, SafeAreas(rects=rects, edges=e.astype(np.int64), weights=weights, portals=portals)

    # ------------------------------------------------------------------ internals

    def _slots_meeting(self, tiles: np.ndarray) -> np.ndarray:
        """Alive slots whose rectangle meets any of the given tiles."""
        t = self.tile
        ti, tj = np.divmod(tiles, self._ntx)
        if self._use_kernel:
            dirty = np.zeros((self._nty, self._ntx), dtype=bool)
            dirty[ti, tj] = True
            got = area_kernel.slots_meeting(self.alive, self.boxes, t, dirty)
            if got is not None:
                return got
        slots = np.flatnonzero(self.alive)
        b = self.boxes[slots]
        # prefilter with the dirty tiles' bounding box
        near = ((b[:, 0] < (ti.max() + 1) * t) & (b[:, 2] > ti.min() * t)
                & (b[:, 1] < (tj.max() + 1) * t) & (b[:, 3] > tj.min() * t))
        slots, b = slots[near], b[near]
        if not len(slots):
            return slots
        dirty = np.zeros((self._nty, self._ntx), dtype=bool)
        dirty[ti, tj] = True
        # tile spans of each rectangle; most span one or a few tiles
        a0, a1 = b[:, 0] >> self._lt, (b[:, 2] - 1) >> self._lt
        c0, c1 = b[:, 1] >> self._lt, (b[:, 3] - 1) >> self._lt
        n = (a1 - a0 + 1) * (c1 - c0 + 1)
        k = np.repeat(np.arange(len(b)), n)
        r = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        w = (c1 - c0 + 1)[k]
        hit = dirty[a0[k] + r // w, c0[k] + r % w]
        return np.unique(slots[k[hit]])

    def _leaves(self, tiles: np.ndarray) -> np.ndarray:
        """Free quadtree leaves (cell boxes) of the given tiles, from the count pyramid
        (compiled: depth first per tile; NumPy: level by level; the same leaves)."""
        ny, nx = self.shape
        if self._use_kernel:
            got = area_kernel.tile_leaves(self._pyr, tiles, self._ntx, self.tile, self.shape, self.min_cell)
            if got is not None:
                return got
        ti, tj = np.divmod(tiles, self._ntx)
        i0 = ti.astype(np.int64) * self.tile
        j0 = tj.astype(np.int64) * self.tile
        out = []
        qi = np.array([0, 0, 1, 1], dtype=np.int64)
        qj = np.array([0, 1, 0, 1], dtype=np.int64)
        m = self.min_cell
        for log_size in range(self._lt, -1, -1):
            if not i0.size:
                break
            size = 1 << log_size
            count = self._levels[log_size][i0 >> log_size, j0 >> log_size]
            area = (np.minimum(i0 + size, ny) - i0) * (np.minimum(j0 + size, nx) - j0)
            free = count == 0
            is_leaf = (free | (count == area)) if size // 2 >= m else np.ones(i0.size, dtype=bool)
            f = free & is_leaf
            out.append(np.stack([i0[f], j0[f], np.minimum(i0[f] + size, ny), np.minimum(j0[f] + size, nx)], axis=1))
            mixed = ~is_leaf
            half = size // 2
            ci = (i0[mixed][:, None] + half * qi).ravel()
            cj = (j0[mixed][:, None] + half * qj).ravel()
            keep = (ci < ny) & (cj < nx)
            i0, j0 = ci[keep], cj[keep]
        return np.concatenate(out) if out else np.zeros((0, 4), dtype=np.int64)

    def _pieces(self, slots: np.ndarray, dirty: np.ndarray) -> np.ndarray:
        """Parts of the rectangles ``slots`` lying in clean tiles, cut along tile lines."""
        if not len(slots):
            return np.zeros((0, 4), dtype=np.int64)
        b = self.boxes[slots]
        if self._use_kernel:
            got = area_kernel.clean_pieces(b, self.tile, dirty)
            if got is not None:
                return got
        lt, t = self._lt, self.tile
        a0, a1 = b[:, 0] >> lt, (b[:, 2] - 1) >> lt
        c0, c1 = b[:, 1] >> lt, (b[:, 3] - 1) >> lt
        n = (a1 - a0 + 1) * (c1 - c0 + 1)
        k = np.repeat(np.arange(len(b)), n)
        r = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        w = (c1 - c0 + 1)[k]
        ta, tc = a0[k] + r // w, c0[k] + r % w
        clean = ~dirty[ta, tc]
        k, ta, tc = k[clean], ta[clean], tc[clean]
        bk = b[k]
        return np.stack([np.maximum(bk[:, 0], ta * t), np.maximum(bk[:, 1], tc * t),
                         np.minimum(bk[:, 2], (ta + 1) * t), np.minimum(bk[:, 3], (tc + 1) * t)], axis=1)

    def _rebuild_tiles(self, tiles: np.ndarray, removed: np.ndarray, dirty: np.ndarray | None = None) -> None:
        if dirty is None:
            dirty = np.zeros((self._nty, self._ntx), dtype=bool)
            dirty.reshape(-1)[tiles] = True
        pieces = self._pieces(removed, dirty)
        leaves = self._leaves(tiles)
        local = np.concatenate([pieces, leaves])
        new = None
        if self._use_kernel and len(local):
            new = area_kernel.merge_boxes(local)
        if new is None:
            new = merge_rects(local) if len(local) else local.reshape(0, 4)
        # free the removed slots and their edges
        if len(removed):
            self.alive[removed] = False
            kept = area_kernel.drop_dead_edges(self.edges, self.alive) if self._use_kernel else None
            if kept is None:
                dead = np.zeros(len(self.alive), dtype=bool)
                dead[removed] = True
                e = self.edges
                kept = e[~(dead[e[:, 0]] | dead[e[:, 1]])]
            self.edges = kept
            self._free_slots.extend(removed.tolist())
        slots = self._take_slots(len(new))
        self.boxes[slots] = new
        self.alive[slots] = True
        self._link(slots, new)

    def _take_slots(self, n: int) -> np.ndarray:
        reuse = min(n, len(self._free_slots))
        slots = [self._free_slots.pop() for _ in range(reuse)]
        extra = n - reuse
        if extra:
            start = len(self.alive)
            cap = max(start + extra, 2 * start)
            grown = np.zeros((cap, 4), dtype=np.int64)
            grown[:start] = self.boxes
            self.boxes = grown
            alive = np.zeros(cap, dtype=bool)
            alive[:start] = self.alive
            self.alive = alive
            slots.extend(range(start, start + extra))
            self._free_slots.extend(range(cap - 1, start + extra - 1, -1))
        return np.asarray(slots, dtype=np.int64)

    def _link(self, slots: np.ndarray, boxes: np.ndarray) -> None:
        """Add the edges between the new rectangles and every rectangle they touch."""
        if not len(slots):
            return
        if self._use_kernel:
            got = area_kernel.link_edges(slots, self.alive, self.boxes, self._link_scratch)
            if got is not None:
                self.edges = np.concatenate([self.edges, got])
                return
        # candidates: alive rectangles meeting the new ones' bounding box grown by one cell
        alive = np.flatnonzero(self.alive)
        cb = self.boxes[alive]
        near = ((cb[:, 0] <= boxes[:, 2].max()) & (cb[:, 2] >= boxes[:, 0].min())
                & (cb[:, 1] <= boxes[:, 3].max()) & (cb[:, 3] >= boxes[:, 1].min()))
        cand, cb = alive[near], cb[near]
        base = max(self.shape) + 2
        a_parts, b_parts = [], []
        # (far side of a, span of a) against (near side of b, span of b), both orientations
        for far, a0, a1, near_, b0, b1 in (
            (3, 0, 2, 1, 0, 2),  # a's right = b's left (rows overlap)
            (1, 0, 2, 3, 0, 2),  # a's left = b's right
            (2, 1, 3, 0, 1, 3),  # a's top = b's bottom (columns overlap)
            (0, 1, 3, 2, 1, 3),  # a's bottom = b's top
        ):
            ia, ib = _touching(boxes[:, far], boxes[:, a0], boxes[:, a1], cb[:, near_], cb[:, b0], cb[:, b1], base)
            a_parts.append(slots[ia])
            b_parts.append(cand[ib])
        a = np.concatenate(a_parts)
        b = np.concatenate(b_parts)
        cap = len(self.alive)
        # a pair of two new rectangles is found from both sides; unique() keeps one
        key = np.unique(np.minimum(a, b) * cap + np.maximum(a, b))
        self.edges = np.concatenate([self.edges, np.stack([key // cap, key % cap], axis=1)])


def _touching(a_far, a_s0, a_s1, b_near, b_s0, b_s1, base: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (a, b) with ``a_far == b_near`` and spans ``[s0, s1)`` overlapping by > 0.

    The b sides on one line belong to disjoint rectangles, so their spans are disjoint and,
    sorted by start, also sorted by end: each a's partners are one contiguous run, found by
    two binary searches.
    """
    key = b_near * base + b_s0
    order = np.argsort(key)
    start = key[order]
    end = start + (b_s1 - b_s0)[order]
    q = a_far * base + a_s0
    lo = np.searchsorted(end, q, side="right")
    hi = np.searchsorted(start, q + (a_s1 - a_s0), side="left")
    n = np.maximum(hi - lo, 0)
    ia = np.repeat(np.arange(len(q)), n)
    pos = np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(int(n.sum()))
    return ia, order[pos]
