"""Model mismatch: how the simulated plant differs from the controller's nominal model.

Parsed from ``--mismatch KEY=VALUE`` arguments into a frozen :class:`Mismatch`. The physical
keys are applied to a *copy* of the nominal model (through ``mujoco.MjSpec``); the nominal
model is never touched. The signal keys (delay, noise, jitter, solve budget) are applied by
the runner and the controller.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields


class MismatchError(ValueError):
    """A mismatch key or value is invalid (one line: key, rule, value received)."""


# key -> (lower bound, upper bound, unit / meaning). Bounds are inclusive.
_RANGES: dict[str, tuple[float, float, str]] = {
    "wheel_radius": (0.5, 1.5, "scale of the wheel radius"),
    "track": (0.5, 1.5, "scale of the track width"),
    "mass": (0.25, 4.0, "scale of every robot body's mass and inertia"),
    "actuator_gain": (0.1, 2.0, "scale of the wheel actuators' velocity gain"),
    "torque_limit": (0.1, 2.0, "scale of the wheel actuators' torque limit"),
    "friction": (0.05, 2.0, "floor/wheel sliding friction coefficient"),
    "delay": (0, 10, "control steps before a command reaches the wheels"),
    "pos_noise": (0.0, 0.5, "std [m] of Gaussian noise on the measured x, y"),
    "yaw_noise": (0.0, 0.5, "std [rad] of Gaussian noise on the measured yaw"),
    "jitter": (0.0, 0.5, "fraction of dt by which the control period varies"),
    "solve_budget_ms": (0.05, 10_000.0, "wall-time cut-off [ms] of the solver"),
}


@dataclass(frozen=True)
class Mismatch:
    """Plant-vs-model differences. Defaults mean "no mismatch".

    Attributes:
        wheel_radius: scale of the plant's wheel radius (1 = nominal).
        track: scale of the plant's track width (1 = nominal).
        mass: scale of every robot body's mass and inertia (1 = nominal).
        actuator_gain: scale of the wheel actuators' velocity gain kv (1 = nominal).
        torque_limit: scale of the wheel actuators' torque limit (1 = nominal).
        friction: floor/wheel sliding friction coefficient; None keeps the model's.
        delay: [control steps] commands reach the wheels this many steps late.
        pos_noise: [m] std of Gaussian noise on the measured position.
        yaw_noise: [rad] std of Gaussian noise on the measured yaw.
        jitter: fraction of dt by which each control period varies (uniform).
        solve_budget_ms: [ms] wall-clock cut-off of the solver; None keeps the controller's
            own setting (SA-MPC: ``MPCConfig.solve_budget_ms``).
    """

    wheel_radius: float = 1.0
    track: float = 1.0
    mass: float = 1.0
    actuator_gain: float = 1.0
    torque_limit: float = 1.0
    friction: float | None = None
    delay: int = 0
    pos_noise: float = 0.0
    yaw_noise: float = 0.0
    jitter: float = 0.0
    solve_budget_ms: float | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            lo, hi, meaning = _RANGES[f.name]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise MismatchError(f"mismatch {f.name}: expected a finite number ({meaning}), got {value!r}")
            if not lo <= value <= hi:
                raise MismatchError(
                    f"mismatch {f.name}: expected {lo} <= value <= {hi} ({meaning}), got {value!r}"
                )
        if self.delay != int(self.delay):
            raise MismatchError(f"mismatch delay: expected a whole number of control steps, got {self.delay!r}")

    def changed(self) -> dict[str, float]:
        """The keys that differ from "no mismatch", as written to the run JSON."""
        default = Mismatch()
        return {k: v for k, v in asdict(self).items() if v != getattr(default, k)}

    @property
    def physical(self) -> bool:
        """True when the plant's MuJoCo model must be modified."""
        d = self.changed()
        return any(k in d for k in ("wheel_radius", "track", "mass", "actuator_gain", "torque_limit", "friction"))


def parse_mismatch(items: list[str] | tuple[str, ...]) -> Mismatch:
    """Parse ``["wheel_radius=1.1", "delay=1", ...]`` into a :class:`Mismatch`.

    Raises:
        MismatchError: unknown key, malformed item, repeated key or value out of range.
    """
    values: dict[str, float | int] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise MismatchError(f"--mismatch {item!r}: expected KEY=VALUE")
        if key not in _RANGES:
            raise MismatchError(f"--mismatch {item!r}: unknown key {key!r}; expected one of {', '.join(_RANGES)}")
        if key in values:
            raise MismatchError(f"--mismatch {item!r}: key {key!r} given twice")
        try:
            number = float(raw)
        except ValueError:
            raise MismatchError(f"--mismatch {item!r}: expected a number, got {raw!r}") from None
        if key == "delay":
            if number != int(number):
                raise MismatchError(f"--mismatch {item!r}: delay must be a whole number of steps, got {raw!r}")
            number = int(number)
        values[key] = number
    return Mismatch(**values)


def mismatch_keys() -> dict[str, tuple[float, float, str]]:
    """Valid keys with their (lower, upper, meaning)."""
    return dict(_RANGES)


#: names in models/diff_drive.xml that the physical mismatch edits.
_WHEELS = ("left_wheel", "right_wheel")


def mismatched_model(scenario, mismatch: Mismatch):
    """A compiled copy of the scenario's model with the physical mismatch applied.

    Edits go through ``mujoco.MjSpec`` re-parsed from the scenario file, so the nominal
    ``scenario.model`` is never touched:

    - ``wheel_radius``: both wheel geoms' radii scaled (the tyre width is kept) and the
      wheel hubs moved up or down by the change of radius, so the chassis and the casters
      stay at their nominal height above the floor and only the rolling radius differs;
    - ``track``: the wheel bodies' lateral offsets scaled;
    - ``mass``: every robot geom's mass scaled (body inertias follow from the geoms);
    - ``actuator_gain``: the wheel velocity servos' kv scaled (gain and bias);
    - ``torque_limit``: the wheel actuators' force range scaled;
    - ``friction``: sliding friction of the floor and both wheels set to the value (MuJoCo
      takes the larger of two geoms' coefficients, so both are set).

    Args:
        scenario: a loaded :class:`~sanav_mj.scene.Scenario`.
        mismatch: the mismatch; only its physical keys are used here.

    Returns:
        mujoco.MjModel: the modified model (same names, so the plant reads it by name).
    """
    import mujoco

    from sanav_mj.scene import floor_geom_id, scenario_spec

    spec = scenario_spec(scenario)
    m = mismatch
    for name in _WHEELS:
        geom = spec.geom(name)
        body = spec.body(name)
        if m.wheel_radius != 1.0:
            size = list(geom.size)
            r0 = size[0]
            size[0] *= m.wheel_radius
            size[1] *= m.wheel_radius
            geom.size = size
            # Keep the chassis at its nominal height: the hub moves by the change of radius,
            # so the wheels still reach the floor and the casters keep their share of the
            # weight (without this a smaller wheel hangs in the air with the robot resting on
            # its casters, and a larger one lifts the casters and tilts the chassis).
            pos = list(body.pos)
            pos[2] += size[0] - r0
            body.pos = pos
        if m.friction is not None:
            fr = list(geom.friction)
            fr[0] = m.friction
            geom.friction = fr
        if m.track != 1.0:
            pos = list(body.pos)
            pos[1] *= m.track
            body.pos = pos
        act = spec.actuator(name)
        if m.actuator_gain != 1.0:
            gain = list(act.gainprm)
            bias = list(act.biasprm)
            gain[0] *= m.actuator_gain
            bias[2] *= m.actuator_gain
            act.gainprm = gain
            act.biasprm = bias
        if m.torque_limit != 1.0:
            act.forcerange = [v * m.torque_limit for v in act.forcerange]
    if m.friction is not None:
        name = scenario.model.geom(floor_geom_id(scenario.model)).name
        if name:
            floor = spec.geom(name)
        else:  # an unnamed floor: the loader guarantees it is the only colliding plane
            floor = next(
                g for g in spec.worldbody.find_all(mujoco.mjtObj.mjOBJ_GEOM)
                if g.type == mujoco.mjtGeom.mjGEOM_PLANE and (g.contype or g.conaffinity)
            )
        fr = list(floor.friction)
        fr[0] = m.friction
        floor.friction = fr
    if m.mass != 1.0:
        for geom in spec.body("base").find_all(mujoco.mjtObj.mjOBJ_GEOM):
            geom.mass = geom.mass * m.mass
    return spec.compile()
