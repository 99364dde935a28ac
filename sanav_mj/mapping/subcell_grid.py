"""The live grid whose safe cells measure from the sub-cell evidence of return cells.

:class:`~sanav_mj.mapping.live_grid.LiveGrid` knows only that material lies somewhere in a
non-free cell; its safe grid measures the inflation radius from the whole square of every
such cell. With range noise of about a cell the cell just in front of a surface is locked
occupied now and then, and a passage loses up to about a cell per side against the exact
rasterisation of the known map (docs/results.md, "Why the last 15 lidar failures stop").

:class:`SubcellGrid` keeps a second log-odds grid of half the cell edge (the *sub-cells*),
updated by the same scans with the same rules (crossings, returns, hit floor; each beam's
crossings only over its last ``LiveGridConfig.sub_tail`` metres), and counts a *return
cell* (a cell whose floor was raised: it turned occupied on a return and never turns free
again) against the safe grid only with the squares of its sub-cells that are not free of
material, a sub-cell being free of material at log-odds ``<= sub_free_thresh``. The rule
(``LiveGridConfig.sub_cells == 2``):

    a cell is safe iff it is free, and no *material square* lies within the inflation
    radius of its closed square, the material squares being: the whole square of every
    non-free cell that is not a return cell (unknown space), and the square of every
    sub-cell of a return cell that is not free of material (sub-cells outside the sub-cell
    grid count as material).

Guarantee. Assume (i) no material lies in a cell the grid calls free (the assumption of
the plain rule), and (ii) no material lies in a sub-cell of a return cell that is free of
material in the sub-cell grid. Every material point then lies in a material square, so a
safe cell's square is more than the inflation radius from every material point: parts of
a surface no beam hit included, since the rule measures from whole (sub-)squares, never
from end points. Unknown cells keep their whole square and a safe cell is observed free,
so unknown space is never safe.

What (ii) rests on, and what breaks it: a sub-cell holding material is called free when the
log-odds walk drifts down there, i.e. when fewer than ``f* = -l_free / (l_occ - l_free)`` of
the beams reaching it end in it. For one beam at normal incidence with Gaussian range noise
``sigma`` the fraction is
:func:`~sanav_mj.mapping.live_grid.beam_hit_fraction` ``(depth, sub, sigma)``, smallest
for a sub-cell holding a sliver (``depth -> sub``): 0.319 at ``sigma`` 0.02 m on 0.0125 m
sub-cells, above ``f*`` 0.286 (the defaults); from ``sigma`` about 0.0225 m it falls below.
So the rule is used only when the robot file's ``lidar_noise`` keeps the sliver fraction
above ``f*`` (:func:`subcells_hold`, checked by ``eval/lidar.py`` ``lidar_grid``). Not
bounded by that model, and measured offline instead (scripts/lidar_map_fidelity.py,
docs/results.md): the first crossings (a beam overshooting a surface by its noise crosses
sub-cells inside the obstacle before a return lands there: ``sub_free_thresh``), beams
grazing a silhouette (they cross the empty part of a sub-cell holding a sliver and end far
behind: ``sub_tail``), and noise heavier than the robot file says.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from sanav_mj.mapping.live_grid import FREE, LiveGrid, LiveGridConfig, MapUpdate, \
    beam_hit_fraction, dilate_count
from sanav_mj.mapping.occupancy import grid_shape
from sanav_mj.mapping.subcell_kernel import SpreadScratch, spread_items

_CORR = 16  # the correction flag: the cell is a return cell (its floor raised)

#: the correction's items per cell: 0-3 the sub-cells (+1 each where set), 4 the cell itself
#: (+1), 5 its whole square (-1: taking back the commit's count of the non-free cell)
_SIGN = np.array([1, 1, 1, 1, 1, -1], np.int8)

def subcells_hold(resolution: float, sigma: float, config: LiveGridConfig = LiveGridConfig()) -> bool:
    """Whether a sub-cell of ``resolution / 2`` [m] holding any sliver of material drifts
    occupied under Gaussian range noise ``sigma`` [m] (:func:`beam_hit_fraction` of a sliver
    above ``f* = -l_free / (l_occ - l_free)``), the condition assumption (ii) of the module
    rests on. ``sigma`` 0 (no noise): True."""
    if not (math.isfinite(resolution) and resolution > 0 and math.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"resolution must be > 0 and sigma >= 0 [m], got {resolution!r}, {sigma!r}")
    if sigma == 0:
        return True
    sub = 0.5 * resolution
    f_star = -config.l_free / (config.l_occ - config.l_free)
    return bool(beam_hit_fraction(sub * (1 - 1e-9), sub, sigma) > f_star)


def subcell_kernels(inflation: float, resolution: float) -> list[np.ndarray]:
    """Per sub-cell ``k = 2 a + b`` (row half ``a``, column half ``b`` of a cell), the cell
    offsets ``(di, dj)`` whose closed squares lie within ``inflation`` [m] of that sub-cell's
    closed square (ties within 1e-9 m kept, the conservative side).

    Returns:
        Four (K_k, 2) int64 arrays.
    """
    half = 0.5 * resolution
    r = int(math.floor(inflation / resolution + 1e-9)) + 1
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    out = []
    for a in (0, 1):
        for b in (0, 1):
            # in sub-cell units: the sub-cell spans [b, b + 1], the cell at dj spans [2 dj, 2 dj + 2]
            gx = np.maximum(0, np.maximum(2 * dj - (b + 1), b - (2 * dj + 2)))
            gy = np.maximum(0, np.maximum(2 * di - (a + 1), a - (2 * di + 2)))
            keep = np.hypot(gx, gy) * half <= inflation + 1e-9
            out.append(np.stack([di[keep], dj[keep]], axis=1).astype(np.int64))
    return out


class SubcellGrid(LiveGrid):
    """A :class:`LiveGrid` whose safe grid uses the sub-cell evidence of return cells
    (module docstring: the rule and its guarantee).

    The counts are kept in two parts: the commit of :class:`LiveGrid` counts every non-free
    cell with its whole square (as the plain rule, compiled, by row runs when many cells
    change: the map's frontier moves by hundreds of cells a scan); a *correction* per
    return cell (a cell whose floor was raised: it turned occupied on a return) takes its
    whole square back and adds the cell itself and its not-free sub-cells. A return cell
    never turns free again (``hit_floor``), so the correction changes only where a cell
    becomes a return cell or one of its sub-cells flips, a few cells a scan.

    Args: as :class:`LiveGrid`; ``config.sub_cells`` must be 2, ``config.floor_at`` equal
    to ``config.occ_thresh`` (a floor is raised exactly when a cell turns occupied, so every
    change of a correction comes with a state change of the cell or of a sub-cell).

    Attributes:
        fine: the sub-cell grid (:class:`LiveGrid` of ``resolution / 2`` cells, inflation 0,
            the same log-odds rules).
        blocked: (ny, nx) int32 per cell: the number of material squares within the
            inflation radius plus 1 if the cell is not free (safe iff 0).
    """

    def __init__(self, bounds, resolution: float, inflation: float, config: LiveGridConfig = LiveGridConfig()
                 ) -> None:
        if config.sub_cells != 2:
            raise ValueError(f"SubcellGrid needs LiveGridConfig.sub_cells == 2, got {config.sub_cells!r}")
        if config.noise_cells:
            raise ValueError(f"SubcellGrid: LiveGridConfig.noise_cells must be 0, got {config.noise_cells!r}")
        if config.hit_floor is None or config.floor_at is None or config.floor_at != config.occ_thresh:
            raise ValueError("SubcellGrid needs LiveGridConfig.hit_floor set and floor_at == occ_thresh, got "
                             f"hit_floor={config.hit_floor!r}, floor_at={config.floor_at!r}, "
                             f"occ_thresh={config.occ_thresh!r}")
        super().__init__(bounds, resolution, inflation, config)
        # its free threshold is sub_free_thresh: its state changes are the sub-cells' flips
        self.fine = LiveGrid(bounds, 0.5 * self.resolution, 0.0, replace(config, sub_cells=1,
                                                                         free_thresh=config.sub_free_thresh))
        self._fshape = grid_shape(self.bounds, 0.5 * self.resolution)
        # the cells straddling the workspace boundary (occupied from the start) count as
        # return cells from the start, so that a floor is raised only with a state change
        self._hf = np.float32(config.hit_floor)
        self._floor[(self.log_odds.reshape(-1) >= np.float32(config.occ_thresh))] = self._hf
        sub = subcell_kernels(self.inflation + config.sub_margin, self.resolution)
        assert max(int(np.abs(o).max()) for o in sub) <= self._r  # _extra_reach
        self._sub_off = sub + [np.zeros((1, 2), np.int64), self._offsets]
        self._sub_koff = [o[:, 0] * self._pw + o[:, 1] for o in self._sub_off]
        self._sub_koff_all = np.concatenate(self._sub_koff).astype(np.int64)
        self._sub_starts = np.concatenate([[0], np.cumsum([len(o) for o in self._sub_koff])]).astype(np.int64)
        self._sub_scratch = SpreadScratch(len(self._pad))
        self._use_sub_kernel = True  # the compiled spreading when available (False: NumPy, for tests)
        ny, nx = self.shape
        self._code = np.zeros(ny * nx, np.int8)  # _CORR | sub-cell bits of return cells, else 0
        cells = np.arange(ny * nx, dtype=np.int64)
        self._apply(cells, self._codes(cells))

    def _extra_reach(self) -> int:
        """[cells] the sub-cell kernels' reach (inflation + ``sub_margin`` from a half cell)."""
        return max(int(np.abs(o).max()) for o in subcell_kernels(self.inflation + self.config.sub_margin,
                                                                 self.resolution))

    def _codes(self, cells: np.ndarray) -> np.ndarray:
        """(K,) int8 the correction of cells (flat): 0 unless a return cell; a return cell
        ``_CORR`` | bit ``2 a + b`` for each of its sub-cells (row half ``a``, column half
        ``b``) not free in the sub-cell grid (outside it: not free)."""
        nx = self.shape[1]
        fy, fx = self._fshape
        out = np.zeros(len(cells), np.int8)
        ret = self._floor[cells] == self._hf
        if ret.any():
            oi, oj = np.divmod(cells[ret], nx)
            fl = self.fine.log_odds
            ft = np.float32(self.config.sub_free_thresh)
            m = np.full(len(oi), _CORR, np.int8)
            for a in (0, 1):
                for b in (0, 1):
                    fi, fj = 2 * oi + a, 2 * oj + b
                    inside = (fi < fy) & (fj < fx)
                    notfree = np.ones(len(oi), bool)
                    notfree[inside] = fl[fi[inside], fj[inside]] > ft
                    m |= (notfree.astype(np.int8) << (2 * a + b))
            out[ret] = m
        return out

    def _apply(self, cells: np.ndarray, new: np.ndarray) -> np.ndarray:
        """Set the corrections of ``cells`` to ``new`` and spread the difference into the
        counts (compiled, :mod:`~sanav_mj.mapping.subcell_kernel`, or NumPy). Returns the
        sorted flat cells whose count crossed zero."""
        old = self._code[cells]
        ch = old != new
        cells, old, new = cells[ch], old[ch], new[ch]
        self._code[cells] = new
        if not len(cells):
            return np.zeros(0, np.int64)
        ny, nx = self.shape
        ci, cj = np.divmod(cells, nx)
        centre = (ci + self._r) * self._pw + (cj + self._r)
        bit = np.array([1, 2, 4, 8, _CORR, _CORR], np.int8)
        on_n = (new[:, None] & bit) != 0
        on_o = (old[:, None] & bit) != 0
        delta = ((on_n.astype(np.int8) - on_o.astype(np.int8)) * _SIGN).astype(np.int8)
        flipped = None
        if self._use_sub_kernel:
            flipped = spread_items(centre, delta, self._sub_koff_all, self._sub_starts, self._pad, self._sub_scratch)
        if flipped is None:
            flipped = self._spread_numpy(centre, delta)
        pr, pc = np.divmod(flipped, self._pw)
        pr -= self._r
        pc -= self._r
        inside = (pr >= 0) & (pr < ny) & (pc >= 0) & (pc < nx)
        return np.sort(pr[inside] * nx + pc[inside])

    def _spread_numpy(self, centre: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The NumPy reference of :func:`spread_items`: the padded indices whose count crossed zero."""
        idx, dl = [], []
        for k in range(len(self._sub_koff)):
            sel = delta[:, k] != 0
            if sel.any():
                ko = self._sub_koff[k]
                idx.append((centre[sel][:, None] + ko[None, :]).ravel())
                dl.append(np.repeat(delta[sel, k].astype(np.int32), len(ko)))
        if not idx:
            return np.zeros(0, np.int64)
        idx = np.concatenate(idx)
        dl = np.concatenate(dl)
        pad = self._pad
        lo, hi = int(idx.min()), int(idx.max()) + 1
        acc = np.bincount(idx - lo, weights=dl, minlength=hi - lo).astype(np.int32)
        touched = np.flatnonzero(acc)
        acc = acc[touched]
        touched += lo
        was_zero = pad[touched] == 0
        pad[touched] += acc
        return touched[was_zero != (pad[touched] == 0)]

    def _refresh(self, up: MapUpdate, fine_changed: np.ndarray) -> MapUpdate:
        """The material bits of the cells whose state changed and of the parents of the
        sub-cells whose state changed; the safe flips of the commit's self term and of the
        material counts combined (a count that crossed zero in both did not flip)."""
        fx = self._fshape[1]
        fi, fj = np.divmod(fine_changed, fx)
        parents = (fi // 2) * self.shape[1] + fj // 2
        cells = np.unique(np.concatenate([up.state_changed, parents]))
        flips = self._apply(cells, self._codes(cells))
        return MapUpdate(up.state_changed, np.setxor1d(up.safe_changed, flips), up.route_changed)

    def integrate(self, origin, heading: float, ranges, hit, angles) -> MapUpdate:
        """As :meth:`LiveGrid.integrate`; the sub-cell grid takes the same scan."""
        up = super().integrate(origin, heading, ranges, hit, angles)
        tail = self.config.sub_tail
        fup = (self.fine.integrate(origin, heading, ranges, hit, angles) if tail is None
               else self.fine.integrate_tails(origin, heading, ranges, hit, angles, tail))
        return self._refresh(up, fup.state_changed)

    def observe_free(self, cells) -> MapUpdate:
        """As :meth:`LiveGrid.observe_free`; the cells' sub-cells are observed free too."""
        up = super().observe_free(cells)
        c = np.unique(np.asarray(cells, dtype=np.int64).reshape(-1))
        i, j = np.divmod(c, self.shape[1])
        fy, fx = self._fshape
        sub = []
        for a in (0, 1):
            for b in (0, 1):
                fi, fj = 2 * i + a, 2 * j + b
                ok = (fi < fy) & (fj < fx)
                sub.append(fi[ok] * fx + fj[ok])
        fup = self.fine.observe_free(np.concatenate(sub))
        return self._refresh(up, fup.state_changed)

    def material_squares(self) -> np.ndarray:
        """(ny, nx) int8 the material squares per cell: bit ``2 a + b`` (sub-cell row half
        ``a``, column half ``b``) for the not-free sub-cells of a return cell, 15 (the whole
        square) for any other non-free cell, 0 for a free cell."""
        ny, nx = self.shape
        code = self._code.reshape(ny, nx)
        out = np.where(self.states() != FREE, 15, 0).astype(np.int8)
        ret = (code & _CORR) != 0
        out[ret] = code[ret] & 15
        return out

    def blocked_reference(self) -> np.ndarray:
        """(ny, nx) int32 the counts recomputed from scratch (the whole square of every
        non-free cell but a return cell; a return cell itself and its not-free sub-cells,
        from :meth:`material_squares`, by brute force over the kernels): equals
        :attr:`blocked` after any sequence of updates (tested)."""
        ny, nx = self.shape
        ret = ((self._codes(np.arange(ny * nx, dtype=np.int64)) & _CORR) != 0).reshape(ny, nx)
        mat = self.material_squares()
        nonfree = self.states() != FREE
        out = dilate_count(nonfree & ~ret, self._sub_off[5]) + ret.astype(np.int32)
        r = self._r
        for k in range(4):
            m = np.pad(((mat >> k) & 1).astype(np.int32) * ret, r)
            for di, dj in self._sub_off[k]:  # a material sub-cell of C counts at C + (di, dj)
                out += m[r - di:r - di + ny, r - dj:r - dj + nx]
        return out
