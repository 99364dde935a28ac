"""Tests of the BARN-like world generator (cellular-automaton cylinder fields) and its
configuration-space solvability check for the rectangular footprint."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sanav_mj.footprint import Footprint
from sanav_mj.generate import (
    BarnConfig,
    barn_obstacles,
    barn_solvable,
    cellular_automaton,
    footprint_free_space,
    generate_barn_layout,
    generate_barn_scenario,
    nominal_footprint,
    write_barn_scenario,
)
from sanav_mj.scene import Obstacle, load_scenario

REPO = Path(__file__).resolve().parents[1]
FP = Footprint(-0.25, 0.25, -0.215, 0.215)


def cyl(x, y, r=0.075, k=0):
    return Obstacle(f"c{k}", "cylinder", np.array([x, y]), 0.0, np.array([r, r]), 0.5, k)


def test_cellular_automaton_rules_known_answer():
    rng = np.random.default_rng(0)
    # fill 1: everything filled; a filled cell in a full field has >= 3 neighbours (corner) -> stays
    full = cellular_automaton(rng, (4, 5), 1.0, 3, birth=5, death=1)
    assert full.all()
    # death rule: with death=3 a corner cell (3 neighbours) of a full field dies after one round
    once = cellular_automaton(np.random.default_rng(0), (4, 5), 1.0, 1, birth=5, death=3)
    assert not once[0, 0] and not once[-1, -1] and once[1, 1] and once[0, 1]
    empty = cellular_automaton(rng, (4, 5), 0.0, 2)
    assert not empty.any()


def test_nominal_footprint_is_the_deck():
    fp = nominal_footprint()
    assert (fp.xmin, fp.xmax) == pytest.approx((-0.25, 0.25))
    assert (fp.ymin, fp.ymax) == pytest.approx((-0.215, 0.215))


def _corridor(gap, length=1.0, x0=2.0):
    """Two rows of touching cylinders along x at y = +-(gap/2 + r), leaving a straight gap."""
    r = 0.075
    obs = []
    for n, x in enumerate(np.arange(x0, x0 + length + 1e-9, 2 * r)):
        obs.append(cyl(x, gap / 2 + r, k=2 * n))
        obs.append(cyl(x, -gap / 2 - r, k=2 * n + 1))
    # close the sides above and below the corridor with walls of boxes
    obs.append(Obstacle("top", "box", np.array([x0 + length / 2, 1.5]), 0.0, np.array([length / 2 + r, 1.5 - gap / 2 - 2 * r]), 0.5, 99))
    obs.append(Obstacle("bot", "box", np.array([x0 + length / 2, -1.5]), 0.0, np.array([length / 2 + r, 1.5 - gap / 2 - 2 * r]), 0.5, 98))
    return obs


@pytest.mark.parametrize("gap, passable", [(0.40, False), (0.43, False), (0.55, True)])
def test_check_passes_exactly_where_the_rectangle_fits(gap, passable):
    cfg = replace(BarnConfig(), x_min_m=0.0, x_max_m=5.0, start_x_m=0.5, goal_x_m=4.5, field_x0_m=1.0,
                  field_length_m=3.0, field_width_m=3.0)
    assert barn_solvable(_corridor(gap), cfg, FP) is passable


def _rect_disc_distance(pose, fp, c, r):
    x, y, th = pose
    d = np.asarray(c) - np.array([x, y])
    ca, sa = math.cos(th), math.sin(th)
    lx, ly = ca * d[0] + sa * d[1], -sa * d[0] + ca * d[1]
    hx, hy = fp.half_size
    q = np.abs([lx, ly]) - np.array([hx, hy])
    return float(np.linalg.norm(np.maximum(q, 0.0)) + min(max(q[0], q[1]), 0.0)) - r


def test_free_cells_are_free_for_every_pose_in_them():
    """Fast-vs-reference: random poses in free (cell, yaw bin) keep the slack to every cylinder."""
    rng = np.random.default_rng(3)
    cells = cellular_automaton(rng, (20, 20), 0.45, 3, 5, 3)
    cfg = replace(BarnConfig(), field_width_m=3.0, field_length_m=3.0, x_min_m=0.0, x_max_m=6.0,
                  start_x_m=0.5, field_x0_m=1.0, goal_x_m=5.5, yaw_bins=16, check_resolution_m=0.05, slack_m=0.02)
    obs = barn_obstacles(cells, cfg)
    free = footprint_free_space(obs, cfg.bounds, FP, slack=cfg.slack_m, resolution=cfg.check_resolution_m,
                                yaw_bins=cfg.yaw_bins)
    k, i, j = np.nonzero(free)
    pick = rng.choice(k.size, 400, replace=False)
    b, h, K = cfg.bounds, cfg.check_resolution_m, cfg.yaw_bins
    worst = np.inf
    for n in pick:
        for _ in range(5):
            pose = (b[0] + (j[n] + rng.random()) * h, b[1] + (i[n] + rng.random()) * h,
                    (k[n] + rng.random()) * math.pi / K)
            worst = min(worst, min(_rect_disc_distance(pose, FP, o.center, 0.075) for o in obs))
            corners = FP.corners(pose)
            assert np.all(corners[:, 0] >= b[0] - 1e-9) and np.all(corners[:, 0] <= b[2] + 1e-9)
            assert np.all(corners[:, 1] >= b[1] - 1e-9) and np.all(corners[:, 1] <= b[3] + 1e-9)
    assert worst >= cfg.slack_m - 1e-9
    assert free.any() and not free.all()


# a coarser check (5 cm cells, 16 yaw bins) keeps these tests fast; still conservative
FAST = replace(BarnConfig(), check_resolution_m=0.05, yaw_bins=16, slack_m=0.02)


def test_barn_layout_is_seeded_solvable_and_loads(tmp_path):
    a = generate_barn_scenario(4, FAST)
    assert a == generate_barn_scenario(4, FAST)
    assert a != generate_barn_scenario(5, FAST)
    layout = generate_barn_layout(4, FAST)
    assert barn_solvable(layout.obstacles, FAST)
    s = load_scenario(write_barn_scenario(4, tmp_path / "b.xml", FAST))
    assert len(s.obstacles) == len(layout.obstacles) == int(layout.cells.sum())
    assert all(o.kind == "cylinder" and o.half_size[0] == pytest.approx(0.075) for o in s.obstacles)
    np.testing.assert_allclose(s.bounds, BarnConfig().bounds)
    np.testing.assert_allclose(s.goal, [10.0, 0.0])
    # lattice: centres on the 0.15 m lattice
    xs = np.array([o.center[0] for o in s.obstacles])
    np.testing.assert_allclose(np.round((xs - 2.075) / 0.15), (xs - 2.075) / 0.15, atol=1e-6)


def test_barn_config_rejects_bad_values():
    with pytest.raises(ValueError, match="fill_range"):
        BarnConfig(fill_range=(0.5, 0.2))
    with pytest.raises(ValueError, match="start_x_m"):
        BarnConfig(start_x_m=3.0)
    with pytest.raises(ValueError, match="seed"):
        generate_barn_layout(-1)


def test_script_writes_barn_worlds(tmp_path):
    out = tmp_path / "barn"
    res = subprocess.run([sys.executable, str(REPO / "scripts" / "gen_scenarios.py"), "--kind", "barn", "--count", "1",
                          "--seed", "7", "--out", str(out)], capture_output=True, text=True, cwd=REPO,
                         env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 0, res.stderr
    s = load_scenario(out / "barn_0007.xml")
    layout = generate_barn_layout(7)
    np.testing.assert_allclose([o.center for o in s.obstacles], [o.center for o in layout.obstacles])


def test_yaw_wraps_between_the_last_and_the_first_bin():
    """Free set (K=4, 1 x 5 cells): bin 0 holds cells 0-2, bin 3 holds cells 2-4, nothing
    else is free; start in cell 0 and goal in cell 4 connect only through yaw pi == 0."""
    from sanav_mj.generate import footprint_connected

    free = np.zeros((4, 1, 5), dtype=bool)
    free[0, 0, :3] = True
    free[3, 0, 2:] = True
    bounds = (0.0, 0.0, 5.0, 1.0)
    assert footprint_connected(free, bounds, 1.0, (0.5, 0.5), (4.5, 0.5))
    free[3, 0, 2] = False  # no cell free in both bins: no way through
    assert not footprint_connected(free, bounds, 1.0, (0.5, 0.5), (4.5, 0.5))
    assert not footprint_connected(free, bounds, 1.0, (0.5, 0.5), (9.5, 0.5))  # goal outside the grid
