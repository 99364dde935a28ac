"""``SensingConfig.unseen_route`` in the lidar closed loop: the route weighs unseen space
more, the MPC still uses only observed-safe rectangles."""

from __future__ import annotations

from dataclasses import replace

from _helpers import cells_of_box
import sanav_mj.control.sensing as sensing
from sanav_mj.eval.episode import run_scenario
from sanav_mj.eval.lidar import lidar_controller
from sanav_mj.scene import load_scenario


def test_unseen_route_weighs_the_route_and_keeps_the_corridor_observed_safe(monkeypatch):
    sc = load_scenario("u_shape")
    ctrl = lidar_controller(sc)
    assert ctrl.config.unseen_route == 0.0  # opt-in
    ctrl.config = replace(ctrl.config, unseen_route=0.6)
    grown = []
    real = sensing.penalise_unseen

    def counting(areas, seen, origin, resolution, factor):
        out = real(areas, seen, origin, resolution, factor)
        assert factor == 0.6 and seen.shape == ctrl.map.grid.shape
        grown.append(bool((out.weights > areas.weights).any()))
        return out

    monkeypatch.setattr(sensing, "penalise_unseen", counting)

    def on_step(step, trace):
        g = ctrl.map.grid
        safe = g.safe()
        for r in ctrl.records[step].corridor_rects:
            assert safe[cells_of_box(r, g.origin, g.resolution, g.shape)].all(), \
                f"step {step}: corridor rectangle {r} holds unobserved or unsafe cells"

    out = run_scenario(sc, seed=0, sensing="lidar", controller_obj=ctrl, on_step=on_step)
    assert out.document["success"] and out.document["collisions"] == 0
    # the route was weighed at the replans, and unseen space made some weights grow
    assert len(grown) >= 2 and any(grown)
