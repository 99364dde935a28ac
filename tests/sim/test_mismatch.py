"""Mismatch parsing and application to a model copy."""

import numpy as np
import pytest

from sanav_mj.scene import load_scenario
from sanav_mj.sim.mismatch import Mismatch, MismatchError, mismatched_model, parse_mismatch


@pytest.fixture(scope="module")
def u_shape():
    return load_scenario("u_shape")


def test_parse_known_keys():
    m = parse_mismatch(["wheel_radius=1.1", "delay=2", "pos_noise=0.02", "friction=0.3"])
    assert m.wheel_radius == pytest.approx(1.1)
    assert m.delay == 2 and isinstance(m.delay, int)
    assert m.friction == pytest.approx(0.3)
    assert m.changed() == {"wheel_radius": 1.1, "delay": 2, "pos_noise": 0.02, "friction": 0.3}
    assert m.physical


def test_default_is_no_mismatch():
    assert Mismatch().changed() == {}
    assert not Mismatch().physical
    assert not parse_mismatch(["delay=1", "yaw_noise=0.03"]).physical


@pytest.mark.parametrize(
    "items, fragment",
    [
        (["wheel"], "expected KEY=VALUE"),
        (["=1"], "expected KEY=VALUE"),
        (["wheel_radius="], "expected KEY=VALUE"),
        (["bogus=1"], "unknown key 'bogus'"),
        (["wheel_radius=abc"], "expected a number"),
        (["wheel_radius=9"], "expected 0.5 <= value <= 1.5"),
        (["delay=1.5"], "whole number"),
        (["friction=nan"], "finite number"),
        (["delay=1", "delay=2"], "given twice"),
    ],
)
def test_bad_items_are_one_line_errors(items, fragment):
    with pytest.raises(MismatchError) as err:
        parse_mismatch(items)
    assert fragment in str(err.value)
    assert "\n" not in str(err.value)


def test_model_copy_is_modified_and_nominal_untouched(u_shape):
    nominal = u_shape.model
    r0 = float(nominal.geom("left_wheel").size[0])
    y0 = float(nominal.body("left_wheel").pos[1])
    mass0 = float(nominal.body_subtreemass[nominal.body("base").id])
    kv0 = float(nominal.actuator("left_wheel").gainprm[0])
    m = parse_mismatch(["wheel_radius=1.1", "track=0.9", "mass=1.5", "actuator_gain=0.5", "friction=0.3"])
    model = mismatched_model(u_shape, m)
    assert model.geom("left_wheel").size[0] == pytest.approx(1.1 * r0)
    assert model.body("left_wheel").pos[1] == pytest.approx(0.9 * y0)
    assert model.body_subtreemass[model.body("base").id] == pytest.approx(1.5 * mass0)
    assert model.actuator("left_wheel").gainprm[0] == pytest.approx(0.5 * kv0)
    assert model.actuator("left_wheel").biasprm[2] == pytest.approx(-0.5 * kv0)
    assert model.geom("floor").friction[0] == pytest.approx(0.3)
    assert model.geom("right_wheel").friction[0] == pytest.approx(0.3)
    # the nominal model is unchanged
    assert float(nominal.geom("left_wheel").size[0]) == r0
    assert float(nominal.body_subtreemass[nominal.body("base").id]) == mass0
    assert np.isfinite(model.body_mass).all()
