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
    assert ctl._rolled is stale  # the stand-in kept nothing: the step rolled out itself
    for a, b in zip(cmds, expected):
        # the stand-in accepts what the real test accepted here: same plans, same rollouts
        np.testing.assert_array_equal(a.predicted, b.predicted)


def _random_problem(rng, n=20, dt=0.1):
    """A warm start inside random input bounds and the tightest boxes around its rollout
    (each side of a box touching a position, to within +-``slack``)."""
    x0 = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-4, 4)])
    lo = np.column_stack((rng.uniform(-0.5, 0.5, n), rng.uniform(-3, 1, n)))
    hi = lo + np.column_stack((rng.uniform(0, 1.5, n), rng.uniform(0, 3, n)))
    u = lo + rng.uniform(0, 1, (n, 2)) * (hi - lo)
    xs = rollout_np(x0, u, dt)
    pos = xs[1:, :2].ravel()
    return x0, lo.ravel(), hi.ravel(), u, xs, pos


def test_guess_shortcut_agrees_with_the_reach_check():
    """Fast vs reference: whenever the warm start fits (within half the tolerance), the full
    reach check also finds every stage reachable; boxes beside the warm start's positions
    (the shortcut does not apply) are left to the reach check, which finds them."""
    from types import SimpleNamespace

    from sanav_mj.control.reach import unreachable_stage
    from sanav_mj.control.tracking import _guess_fits

    rng = np.random.default_rng(0)
    tol, dt = 1e-3, 0.1
    fits = flagged = 0
    for _ in range(300):
        x0, z_lb, z_ub, u, xs, pos = _random_problem(rng, dt=dt)
        # boxes with sides at the positions, moved in or out by up to half the tolerance
        b_lb = pos - rng.uniform(-0.5, 1.0, pos.size) * 0.5 * tol
        b_ub = pos + rng.uniform(-0.5, 1.0, pos.size) * 0.5 * tol
        u_in = u + rng.uniform(-1, 1, u.shape) * 0.5 * tol
        xs_in = rollout_np(x0, u_in, dt)
        con = SimpleNamespace(pos_lb=b_lb, pos_ub=b_ub)
        prob = SimpleNamespace(u_guess=u_in, guess=xs_in, z_lb=z_lb, z_ub=z_ub)
        ok = _guess_fits(x0, con, prob, 0.5 * tol)
        fits += ok
        if ok:
            assert unreachable_stage(x0, z_lb, z_ub, b_lb, b_ub, dt, tol) is None
        # a box 5 m beside stage 7's position in x (out of reach): the shortcut must not answer
        far_lb, far_ub = b_lb.copy(), b_ub.copy()
        far_lb[12] = far_ub[12] = pos[12] + 5.0
        con_far = SimpleNamespace(pos_lb=far_lb, pos_ub=far_ub + 0.01)
        assert not _guess_fits(x0, con_far, prob, 0.5 * tol)
        k = unreachable_stage(x0, z_lb, z_ub, far_lb, far_ub + 0.01, dt, tol)
        flagged += k is not None
    assert fits > 100 and flagged > 250
