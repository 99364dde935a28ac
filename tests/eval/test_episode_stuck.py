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
