"""Tests of the BARN metric and the world measures behind it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sanav_mj.eval.barn import barn_score, clearance_grid, optimal_path_length, widest_disc
from sanav_mj.scene import Obstacle

BOUNDS = np.array([0.0, -1.0, 4.0, 1.0])


def cyl(x, y, r, k=0):
    return Obstacle(f"c{k}", "cylinder", np.array([x, y]), 0.0, np.array([r, r]), 0.5, k)


def test_barn_score_known_values():
    assert barn_score(True, 10.0, 5.0) == pytest.approx(0.5)
    assert barn_score(True, 4.0, 5.0) == pytest.approx(0.5)  # clipped below at 2 t_opt
    assert barn_score(True, 20.0, 5.0) == pytest.approx(0.25)
    assert barn_score(True, 100.0, 5.0) == pytest.approx(1 / 8)  # clipped above at 8 t_opt
    assert barn_score(False, 10.0, 5.0) == 0.0
    with pytest.raises(ValueError, match="t_opt"):
        barn_score(True, 1.0, 0.0)


def test_optimal_path_straight_and_around_a_disc():
    res = 0.02
    start, goal = (0.51, 0.01), (3.51, 0.01)  # cell centres: no endpoint offsets
    assert optimal_path_length((), BOUNDS, start, goal, 0.2, res) == pytest.approx(3.0, abs=1e-9)
    # a disc of radius 0.3 + clearance 0.2 on the line: the shortest path wraps a circle of
    # radius 0.5 (tangents + arc); the 16-connected grid is at most 2.7 % longer and the
    # centre test may cut the clearance by half a cell
    r = 0.5
    d = 1.5  # from each endpoint to the centre
    tangent = math.sqrt(d * d - r * r)
    arc = r * (math.pi - 2 * math.acos(r / d))
    exact = 2 * tangent + arc
    got = optimal_path_length((cyl(2.01, 0.01, 0.3),), BOUNDS, start, goal, 0.2, res)
    assert exact * (1 - 0.02) <= got <= exact * 1.03
    # blocked: a wall of discs across the workspace
    wall = tuple(cyl(2.0, y, 0.1, k) for k, y in enumerate(np.arange(-1.0, 1.01, 0.1)))
    assert optimal_path_length(wall, BOUNDS, start, goal, 0.2, res) == math.inf


def test_widest_disc_is_half_the_gap():
    # two discs of radius 0.2 at y = +-0.5: gap 0.6 between them, 0.3 to the workspace edge
    obs = (cyl(2.0, 0.5, 0.2, 0), cyl(2.0, -0.5, 0.2, 1))
    got = widest_disc(obs, BOUNDS, (0.5, 0.0), (3.5, 0.0), resolution=0.01, tol=1e-4)
    assert got == pytest.approx(0.3, abs=0.01)


def test_clearance_grid_round_fast_path_matches_signed_distance():
    rng = np.random.default_rng(1)
    obs = [cyl(*rng.uniform([0, -1], [4, 1]), rng.uniform(0.05, 0.2), k) for k in range(12)]
    obs.append(Obstacle("b", "box", np.array([1.0, 0.2]), 0.4, np.array([0.3, 0.1]), 0.5, 99))
    dist, pts = clearance_grid(obs, BOUNDS, 0.05)
    ref = np.min([o.signed_distance(pts.reshape(-1, 2)) for o in obs], axis=0).reshape(dist.shape)
    np.testing.assert_allclose(dist, ref, atol=1e-12)


def test_barn_eval_script_worlds_and_score(tmp_path):
    import csv
    import subprocess
    import sys
    from pathlib import Path

    from sanav_mj.generate import write_barn_scenario

    repo = Path(__file__).resolve().parents[2]
    world = write_barn_scenario(3, tmp_path / "barn_0003.xml")
    env = {"PYTHONPATH": str(repo), "PATH": "/usr/bin:/bin"}
    out = tmp_path / "worlds.csv"
    res = subprocess.run([sys.executable, str(repo / "scripts" / "barn_eval.py"), "worlds", str(world), "--out", str(out),
                          "--configs", "0.05@0.05"], capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    row = next(csv.DictReader(open(out)))
    assert float(row["L_m"]) >= 10.0 - 1e-9  # never shorter than the straight line
    assert float(row["t_opt_s"]) == pytest.approx(float(row["L_m"]) / 2.0)
    bench = tmp_path / "bench"
    bench.mkdir()
    t_opt = float(row["t_opt_s"])
    with open(bench / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["scenario", "controller", "seed", "success", "reason", "sim_time_s", "collisions"])
        w.writeheader()
        w.writerow(dict(scenario="barn_0003", controller="sa-mpc", seed=0, success=True, reason="goal",
                        sim_time_s=4 * t_opt, collisions=0))
        w.writerow(dict(scenario="barn_0003", controller="sa-mpc", seed=1, success=False, reason="no_path",
                        sim_time_s="", collisions=0))
    res = subprocess.run([sys.executable, str(repo / "scripts" / "barn_eval.py"), "score", str(bench), "--worlds", str(out)],
                         capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    scores = [float(r["barn_score"]) for r in csv.DictReader(open(bench / "barn_scores.csv"))]
    assert scores == pytest.approx([0.25, 0.0])
