"""ScanLocaliser (sanav_mj.control.localisation): prediction and blending, known answers."""

import math

import numpy as np

from sanav_mj.control.base import Observation
from sanav_mj.control.localisation import ScanLocaliser
from sanav_mj.control.sensing_config import SensingConfig


class _NoMap:
    """A map that must not be asked for a match (the observations carry no scan)."""

    def match(self, *args, **kwargs):  # pragma: no cover - failing is the point
        raise AssertionError("no scan: the localiser must not match")


def test_without_localising_the_measured_pose_is_used_and_the_scan_added():
    loc = ScanLocaliser(SensingConfig(localise=False), np.zeros(3))
    pose, add = loc.localise(Observation(t=0.0, pose=np.array([1.0, 2.0, 0.3]), velocity=np.zeros(2)), _NoMap())
    assert add and np.array_equal(pose, [1.0, 2.0, 0.3])
    assert loc.match_log[-1][0] == "none"


def test_odometry_prediction_and_blend_without_a_scan():
    # one step of 0.1 s at v = 1 m/s, w = 0.5 rad/s from the start pose (0, 0, 0): the
    # midpoint-heading unicycle step gives (0.1 cos 0.025, 0.1 sin 0.025, 0.05); the measured
    # pose equals that prediction, so the variance blend leaves it exactly there
    cfg = SensingConfig()
    loc = ScanLocaliser(cfg, np.zeros(3))
    loc.localise(Observation(t=0.0, pose=np.zeros(3), velocity=np.array([1.0, 0.5])), _NoMap())
    pred = np.array([0.1 * math.cos(0.025), 0.1 * math.sin(0.025), 0.05])
    pose, add = loc.localise(Observation(t=0.1, pose=pred.copy(), velocity=np.array([1.0, 0.5])), _NoMap())
    assert add
    np.testing.assert_allclose(pose, pred, rtol=0, atol=4 * np.finfo(float).eps)
    # a measurement 1 cm off in x is blended by odometry_sigma^2 / (odometry_sigma^2 + var)
    loc2 = ScanLocaliser(cfg, np.zeros(3))
    pose2, _ = loc2.localise(Observation(t=0.0, pose=np.array([0.01, 0.0, 0.0]), velocity=np.zeros(2)), _NoMap())
    k = cfg.odometry_sigma[0] ** 2 / (cfg.odometry_sigma[0] ** 2 + cfg.meas_sigma0[0] ** 2)
    assert math.isclose(pose2[0], 0.01 * k, rel_tol=0, abs_tol=4 * np.finfo(float).eps)
