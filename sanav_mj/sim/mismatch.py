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
        solve_budget_ms: [ms] wall-clock cut-off of the solver; None for no cut-off.
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
