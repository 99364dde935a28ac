"""Issue 12: ``stuck`` measures progress along the planned route, not towards the goal."""

from __future__ import annotations

from sanav_mj.eval.episode import run_scenario
from sanav_mj.scene import load_scenario

# A serpentine: floor x [-1.5, 11.5], y [-1.5, 5.5]; wall 1 at y = 1.1 open on the right,
# wall 2 at y = 3.3 open on the left. From (0, 0) to (6, 4.4) the route runs 10 m to the
# right (away from the goal), back 10 m to the left, then 6 m to the right.
SERPENTINE = (
    '<geom name="fold1" type="box" pos="3.75 1.1 0.25" size="5.25 0.1 0.25"/>\n'
    '<geom name="fold2" type="box" pos="6.25 3.3 0.25" size="5.25 0.1 0.25"/>'
)
FLOOR = '<geom name="floor" type="plane" pos="5 2 0" size="6.5 3.5 0.1"/>'


def test_serpentine_route_leading_away_from_the_goal_reaches_it(write_scenario):
    """Before the fix this run ended "stuck after 8.1 s" (the straight-line distance grew
    while the robot drove along the first leg at about 1 m/s)."""
    path = write_scenario(SERPENTINE, name="serpentine", start="0 0 0", goal="6 4.4", floor=FLOOR)
    scenario = load_scenario(path)
    out = run_scenario(scenario, controller="sa-mpc", seed=0)
    doc = out.document
    assert out.prepared.plan.ok and out.prepared.plan.corridor.size >= 3
    assert doc["reason"] == "goal", doc["reason"]
    assert doc["path_length_m"] > 25.0  # it really drove the folds (straight line: 7.6 m)
    assert doc["collisions"] == 0


class _Stop(Exception):
    pass


def test_only_sa_mpc_is_judged_along_the_route(monkeypatch):
    """SA-MPC tracks the plan; the penalty MPC (straight reference), DWA and the DQN do not,
    so they keep the straight-line progress (the DQN's training rule)."""
    import numpy as np

    import sanav_mj.sim.runner as runner

    seen = {}

    def spy(*args, route=None, **kwargs):
        seen["route"] = route
        raise _Stop

    monkeypatch.setattr(runner, "run_episode", spy)
    for name, follows in (("sa-mpc", True), ("mpc", False), ("dwa", False), ("dqn", False)):
        try:
            run_scenario("single_rect", controller=name, seed=0, controller_obj=object())
        except _Stop:
            pass
        if follows:
            route = seen["route"]
            assert route.shape[1] == 2 and route.shape[0] > 10
            np.testing.assert_array_equal(route[-1], load_scenario("single_rect").goal)
        else:
            assert seen["route"] is None, name
