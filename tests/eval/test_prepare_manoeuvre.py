"""The discs mode's refine fallback and manoeuvres on a world the default map closes
(the BARN-like world of seed 17: no path at refine 2; at refine 4 the corridor reference
turns on the spot where the footprint has no room)."""

from dataclasses import replace

import numpy as np
import pytest

from sanav_mj.control.spec import ControllerSpec
from sanav_mj.eval.prepare import prepare, replan_prepared
from sanav_mj.footprint import robot_footprint
from sanav_mj.generate import write_barn_scenario
from sanav_mj.planning.manoeuvre import union_admissible
from sanav_mj.planning.pose_search import member_boxes


def _spec(**kw):
    return ControllerSpec("sa-mpc", replace(ControllerSpec().sa_mpc, footprint="discs", **kw))


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    return write_barn_scenario(17, tmp_path_factory.mktemp("barn") / "barn_0017.xml")


@pytest.fixture(scope="module")
def prepared(world):
    return prepare(world, controller=_spec())


def test_default_discs_mode_refines_where_no_path_and_follows_manoeuvres(world, prepared):
    off = prepare(world, controller=_spec(footprint_refine_fallback=0))
    assert not off.plan.ok and off.plan.reason == "no_path" and not off.refine_fallback
    p = prepared
    assert p.refine_fallback and p.plan.ok
    assert p.grid.resolution == pytest.approx(0.05 / 4, rel=1e-12)
    assert p.plan.info["manoeuvre"] == "2 stretches"
    assert p.plan.disc_corridors is not None  # followed as a pose route, one chain per disc
    assert p.plan.info["grown_members"] == ControllerSpec().sa_mpc.footprint_manoeuvre.grow
    # a plan made again from the start (run_scenario with a Prepared) gets its manoeuvres too
    again = replan_prepared(p, np.asarray(p.scenario.start, float), _spec())
    assert again.refine_fallback and again.plan.info["manoeuvre"] == "2 stretches"


def test_manoeuvres_off_keep_the_corridor_plan(world):
    p = prepare(world, controller=_spec(footprint_manoeuvre=None))
    assert p.refine_fallback and p.plan.ok and p.plan.disc_corridors is None and "manoeuvre" not in p.plan.info


def test_grown_members_hold_the_plain_ones_and_only_free_cells(prepared):
    p = prepared
    plain = member_boxes(p.areas, 0.0)
    grown = member_boxes(p.areas, 0.0, grow=0.25)
    assert np.all(grown[:, :2] <= plain[:, :2]) and np.all(grown[:, 2:] >= plain[:, 2:])
    assert np.all(grown[:, :2] >= plain[:, :2] - 0.25 - 1e-9) and np.all(grown[:, 2:] <= plain[:, 2:] + 0.25 + 1e-9)
    g = p.grid
    h = g.resolution
    ox, oy = np.asarray(g.origin, float)
    for b in grown[:: max(1, len(grown) // 300)]:  # a sample of them: no occupied cell inside
        j0, j1 = int(round((b[0] - ox) / h)), int(round((b[2] - ox) / h))
        i0, i1 = int(round((b[1] - oy) / h)), int(round((b[3] - oy) / h))
        assert not g.occupied[i0:i1, j0:j1].any()


def test_route_reference_keeps_every_disc_centre_in_a_grown_member(prepared):
    p = prepared
    offsets, _ = robot_footprint(p.scenario.model).discs(3)
    f = union_admissible(member_boxes(p.areas, 0.0, grow=0.25), offsets)
    tol = 0.005  # the route's dense poses are checked with member_chain's 5 mm (pose_reference)
    s = p.plan.reference.states
    ok = f(s)
    if not ok.all():  # within the chain walk's tolerance of a member
        grown = member_boxes(p.areas, 0.0, grow=0.25)
        wide = np.concatenate((grown[:, :2] - tol, grown[:, 2:] + tol), axis=1)
        ok = union_admissible(wide, offsets)(s)
    assert ok.all()
