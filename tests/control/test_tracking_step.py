"""The tracking-MPC step reuses the rollout of the solution its acceptance test made."""

from __future__ import annotations

import numpy as np

from sanav_mj.control.base import Observation
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig
from sanav_mj.control.tracking import TrackingMPC
from sanav_mj.control.unicycle import rollout_np, step_np

from mpc_cases import ROBOT


def _drive(ctl: SAMPC, steps: int, check=None) -> list:
    x = np.array([3.3, 0.6, 0.4])
    ctl.reset(x, progress=40)
    cmds, vel = [], np.zeros(2)
    for k in range(steps):
        cmd = ctl.step(Observation(t=0.1 * k, pose=x, velocity=vel))
        if check is not None:
            check(ctl, cmd)
        cmds.append(cmd)
        vel = np.array([cmd.v, cmd.w])
        x = step_np(x, vel, ctl.dt)
    return cmds


def test_accepted_prediction_is_the_rollout_of_the_applied_plan(l_case):
    areas, plan = l_case
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())

    def check(ctl, cmd):
        assert cmd.status in ("ok", "inexact")
        # exactly the rollout of the stored plan from the step's state (not a stale one)
        np.testing.assert_array_equal(cmd.predicted, rollout_np(cmd.predicted[0], ctl.plan_inputs, ctl.dt))
        z, x0, xs = ctl._rolled
        assert xs is cmd.predicted and np.array_equal(z.reshape(-1, 2), ctl.plan_inputs)

    assert len(_drive(ctl, 3, check)) == 3


def test_an_acceptance_without_rollout_gets_the_step_own_rollout(l_case, monkeypatch):
    """A subclass whose acceptance test rolls nothing out (a stale rollout of an earlier step
    left behind) still gets the rollout of its own solution."""
    areas, plan = l_case
    ref = SAMPC(ROBOT, areas, plan, MPCConfig())
    expected = _drive(ref, 3)
    ctl = SAMPC(ROBOT, areas, plan, MPCConfig())
    _drive(ctl, 1)  # leaves a rollout of step 0 behind
    stale = ctl._rolled
    monkeypatch.setattr(TrackingMPC, "acceptance", lambda self, res, x0, prob: ("ok", ""))
    cmds = _drive(ctl, 3)
    assert ctl._rolled is None and stale is not None
    for a, b in zip(cmds, expected):
        # the stand-in accepts what the real test accepted here: same plans, same rollouts
        np.testing.assert_array_equal(a.predicted, b.predicted)
