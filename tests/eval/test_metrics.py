"""Safe-area violation counts of the run JSON: every constrained point, a step counted once
(:func:`sanav_mj.eval.metrics.step_violations`, :func:`sanav_mj.eval.lidar.outside_safe_areas`)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from sanav_mj.control.config import MPCConfig
from sanav_mj.control.sensed_footprint import SensedFootprint
from sanav_mj.eval.lidar import outside_safe_areas
from sanav_mj.eval.metrics import body_points, safe_area_violations, step_violations
from sanav_mj.footprint import Footprint
from sanav_mj.mapping.safe_areas import SafeAreas

EPS = np.finfo(float).eps
OFFSETS = np.array([[-1 / 6, 0.0], [0.0, 0.0], [1 / 6, 0.0]])  # three disc centres along x
RECTS = np.array([[0.0, 0.0, 1.0, 1.0]])
# base inside (0.9, 0.5); heading +x: the front centre at x = 0.9 + 1/6 = 1.067, outside
FRONT_OUT = np.array([0.9, 0.5, 0.0])
# the same position heading +y: every centre inside (y = 0.333 .. 0.667)
ALL_IN = np.array([0.9, 0.5, math.pi / 2])
# base outside (1.05, 0.5), heading -x: the front centre at x = 1.05 - 1/6 = 0.883 inside, the
# rear one at 1.217 outside
BASE_OUT = np.array([1.05, 0.5, math.pi])


def test_body_points_are_the_rotated_offsets():
    pts = body_points(np.array([FRONT_OUT, ALL_IN]), OFFSETS)
    assert pts.shape == (2, 3, 2)
    np.testing.assert_allclose(pts[0], [[0.9 - 1 / 6, 0.5], [0.9, 0.5], [0.9 + 1 / 6, 0.5]], rtol=0, atol=4 * EPS)
    np.testing.assert_allclose(pts[1], [[0.9, 0.5 - 1 / 6], [0.9, 0.5], [0.9, 0.5 + 1 / 6]], rtol=0, atol=4 * EPS)
    np.testing.assert_array_equal(body_points(np.array([FRONT_OUT]), None), [[[0.9, 0.5]]])


def test_a_step_counts_when_any_disc_centre_is_outside_once():
    poses = np.array([FRONT_OUT, ALL_IN, BASE_OUT, FRONT_OUT])
    # the base point alone sees only BASE_OUT; every centre: FRONT_OUT twice and BASE_OUT once
    assert step_violations(poses, RECTS) == safe_area_violations(poses[:, :2], RECTS) == 1
    assert step_violations(poses, RECTS, OFFSETS) == 3
    assert step_violations(poses[:0], RECTS, OFFSETS) == 0
    assert step_violations(poses, np.zeros((0, 4)), OFFSETS) == 4
    # a second rectangle holding the front centre: no longer counted
    assert step_violations(poses, np.vstack((RECTS, [[1.0, 0.4, 1.1, 0.6]])), OFFSETS) == 1


def _sensing(mode: str, rects):
    """A stand-in for a SensingSAMPC after its first plan: the footprint part and safe areas."""
    body = SensedFootprint.of(MPCConfig(footprint=mode), Footprint(-0.25, 0.25, -0.2, 0.2), 0.0)
    areas = SafeAreas(np.asarray(rects, float), np.zeros((0, 2), np.int64), np.zeros(0), np.zeros((0, 2, 2)))
    return SimpleNamespace(mpc=object(), areas=areas, body=body)


def test_lidar_run_counts_every_disc_centre_in_discs_mode_and_the_position_in_disc_mode():
    discs = _sensing("discs", RECTS)
    np.testing.assert_allclose(discs.body.offsets, OFFSETS, rtol=0, atol=EPS)
    assert outside_safe_areas(discs, FRONT_OUT) == 1  # the base is inside, the front centre is not
    assert outside_safe_areas(discs, ALL_IN) == 0
    assert outside_safe_areas(discs, BASE_OUT) == 1
    disc = _sensing("disc", RECTS)
    assert outside_safe_areas(disc, FRONT_OUT) == 0 and outside_safe_areas(disc, BASE_OUT) == 1
    # before the first plan or the first scan: not counted
    assert outside_safe_areas(SimpleNamespace(mpc=None, areas=discs.areas, body=discs.body), BASE_OUT) == 0
    assert outside_safe_areas(SimpleNamespace(mpc=object(), areas=None, body=discs.body), BASE_OUT) == 0


def test_run_json_counts_the_constrained_points_of_the_mode():
    """``episode_json(points=...)`` (the known-map runs): the discs mode passes its disc
    centres (:func:`sanav_mj.eval.episode.constrained_points`), the disc mode nothing."""
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.episode import constrained_points
    from sanav_mj.eval.metrics import episode_json
    from sanav_mj.eval.prepare import footprint_spec
    from sanav_mj.footprint import robot_footprint
    from sanav_mj.scene import load_scenario
    from sanav_mj.sim.runner import Episode, EpisodeTrace

    tr = EpisodeTrace()
    for p in (FRONT_OUT, ALL_IN, BASE_OUT):
        tr.t.append(0.0)
        tr.pose.append(p.copy())
        tr.cmd.append((0.0, 0.0))
        tr.solve_ms.append(0.0)
        tr.pipeline_ms.append(0.0)
        tr.clearance.append(1.0)
    ep = Episode(success=False, reason="timeout", steps=3, sim_time_s=0.3, collisions=0, solver_failures=0,
                 final_pose=BASE_OUT.copy(), trace=tr, wall_time_s=0.0)

    def count(points):
        return episode_json(ep, scenario="s", controller="sa-mpc", seed=0, start=ALL_IN, goal=np.zeros(2),
                            rects=RECTS, mismatch={}, points=points)["safe_area_violations"]

    assert count(None) == 1 and count(OFFSETS) == 2
    sc = load_scenario("single_rect")
    assert constrained_points(sc, ControllerSpec("sa-mpc")) is None
    assert constrained_points(sc, ControllerSpec("mpc")) is None
    np.testing.assert_array_equal(constrained_points(sc, footprint_spec("sa-mpc", "discs")),
                                  robot_footprint(sc.model).discs(3)[0])
