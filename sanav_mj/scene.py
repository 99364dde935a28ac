"""Load a scenario (MJCF path or built-in name) into a :class:`Scenario`.

A scenario file includes the robot (``models/diff_drive.xml``) and adds a floor plane, static
obstacle geoms and ``<custom>`` numerics ``start`` (x [m], y [m], yaw [rad]) and ``goal``
(x [m], y [m]). The format is documented in docs/scenarios.md.

Everything downstream (mapping, planning, control, sim) works from the :class:`Scenario`
returned here; nothing downstream re-parses the XML.

Rules applied by :func:`load_scenario` (each violation is a one-line :class:`ScenarioError`
naming the file):

- **Robot**: a body ``base`` with a free joint (the robot's root), with the names that
  :func:`robot_params` reads. A file outside this repository includes the robot either by
  absolute path (``<include file="/abs/path/models/diff_drive.xml"/>``) or as
  ``<include file="diff_drive.xml"/>``: when MuJoCo cannot open an included file whose name
  ends in ``diff_drive.xml``, the packaged robot is supplied in its place (a file of that
  name that does exist next to the scenario always wins).
- **Floor**: exactly one horizontal, axis-aligned ``plane`` geom of finite size among the
  static geoms; the workspace is its rectangle ``pos +/- size``.
- **Obstacles**: every other static geom that can collide with the robot (its
  contype/conaffinity bits match a robot geom's). Static geoms are the world body's own geoms
  and those of bodies welded to the world (child bodies without joints, not mocap); grouping
  obstacles in such bodies is allowed. Supported: ``box`` with one of its axes vertical
  (any yaw), upright ``cylinder`` and ``capsule``. Anything else (sphere, ellipsoid, mesh,
  height field, a tilted box/cylinder/capsule, a second plane) is an error, never skipped.
  Geoms that cannot collide with the robot (``contype="0" conaffinity="0"``, decoration) are
  not obstacles. Bodies that move (joints other than the robot's, mocap) are an error.
- **Start / goal**: ``start`` has 3 finite values, ``goal`` 2; both lie inside the workspace
  shrunk by the inflation radius ``footprint_radius + margin`` and at least that far from
  every obstacle's footprint.
- **Numbers**: every geom's position, size and orientation and every body's position and
  orientation are finite (no NaN / inf); the robot's parameters lie in :data:`ROBOT_RANGES`;
  ``<option timestep>`` is finite and > 0, and before a run :func:`check_timestep` requires
  10 to 1000 physics steps per control period (:data:`STEPS_PER_PERIOD`).
- **MuJoCo's messages**: its warnings are kept in memory (:func:`mujoco_warnings`), never
  printed to stderr or written to ``MUJOCO_LOG.TXT``.
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import mujoco
import numpy as np

from sanav_mj.resources import builtin_scenarios, robot_model_path, scenarios_dir

ObstacleKind = Literal["box", "cylinder", "capsule"]

#: Names in the robot model that :func:`robot_params` and the plant read.
ROBOT_BASE = "base"
WHEEL_NAMES = ("left_wheel", "right_wheel")  # geom, body, joint and actuator names
ROBOT_LIMITS = "robot_limits"  # custom numeric: a_max, alpha_max, w_cap

#: An axis counts as vertical when |cos(angle to world z)| exceeds this.
_VERTICAL_TOL = 1e-6


class ScenarioError(ValueError):
    """A scenario file or name is unusable. The message is one line naming the file and the rule."""


#: Physical ranges of the robot parameters :func:`robot_params` reads, ``name: (low, high, unit, why)``.
#: They bracket real wheeled ground robots with a wide margin; a value outside is a typo or a unit
#: error (a wheel speed range of 1e12 rad/s), never a robot the controllers (0.1 s period) can drive.
ROBOT_RANGES: dict[str, tuple[float, float, str, str]] = {
    "wheel_radius": (0.005, 1.0, "m", "wheels of ground robots, 5 mm to 1 m"),
    "track": (0.02, 5.0, "m", "wheel spacing of ground robots, 2 cm to 5 m"),
    "footprint_radius": (0.01, 10.0, "m", "robot footprint, 1 cm to 10 m"),
    "wheel_speed_max": (0.01, 1000.0, "rad/s", "wheel speed limit, up to about 9 500 rpm"),
    "v_max": (0.01, 20.0, "m/s", "top speed; at 20 m/s a 0.1 s control period already spans 2 m"),
    "a_max": (0.01, 50.0, "m/s^2", "acceleration, up to 5 g (traction allows about 1 g)"),
    "alpha_max": (0.01, 500.0, "rad/s^2", "yaw acceleration"),
    "w_cap": (0.01, 50.0, "rad/s", "yaw-rate cap, up to 8 turns per second"),
    "mass": (0.01, 10000.0, "kg", "total robot mass, 10 g to 10 t"),
}

#: Bounds on the number of physics steps per control period (``control period / <option timestep>``).
#: At least 10: the plant holds each command for a whole number of steps, so the hold differs from
#: the period by up to half a step (<= 5 % at 10 steps), and contacts need several steps per period.
#: At most 1000 (0.1 ms at a 0.1 s period): the robot model steps in about 20 us, so a 60 s run costs
#: about 12 s of physics; 1e-7 s would be a million steps per period (the run never ends).
STEPS_PER_PERIOD = (10, 1000)

_MUJOCO_WARNINGS: deque[str] = deque(maxlen=100)


def _keep_mujoco_warning(message: str) -> None:
    _MUJOCO_WARNINGS.append(str(message).strip())


def capture_mujoco_warnings() -> None:
    """Route MuJoCo's warnings to :func:`mujoco_warnings` instead of stderr and ``MUJOCO_LOG.TXT``.

    MuJoCo's default warning handler prints ``WARNING: ...`` to stderr and appends it to
    ``MUJOCO_LOG.TXT`` in the current folder. This installs a handler (process-wide, as MuJoCo's
    handler is global; idempotent) that keeps the last 100 messages in memory instead. Called by
    every function here that compiles a scenario, so loading a file never writes to stderr or
    leaves files behind; problems that matter are reported by the checks as a ScenarioError.
    """
    mujoco.set_mju_user_warning(_keep_mujoco_warning)


def mujoco_warnings() -> list[str]:
    """The last (up to 100) MuJoCo warnings captured since :func:`capture_mujoco_warnings`, oldest first."""
    return list(_MUJOCO_WARNINGS)
@dataclass(frozen=True)
class Obstacle:
    """A static obstacle in the world frame, projected to the floor plane.

    Attributes:
        name: geom name (``geom_<id>`` when the file leaves it unnamed).
        kind: ``"box"`` (any yaw), ``"cylinder"`` or ``"capsule"`` (both standing upright).
        center: (2,) [m] x, y of the geom centre.
        yaw: [rad] rotation about the world z axis (boxes; 0 for round geoms).
        half_size: (2,) [m] half extents along the geom's own x, y axes for boxes;
            ``(radius, radius)`` for cylinders and capsules.
        height: [m] top of the geom above the floor (informational).
        geom_id: MuJoCo geom id in the scenario's compiled model.
    """

    name: str
    kind: ObstacleKind
    center: np.ndarray
    yaw: float
    half_size: np.ndarray
    height: float
    geom_id: int

    def corners(self) -> np.ndarray:
        """(4, 2) [m] corners of a box's footprint, counter-clockwise. Boxes only."""
        if self.kind != "box":
            raise ValueError(f"corners() is defined for boxes, got a {self.kind}")
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        rot = np.array([[c, -s], [s, c]])
        hx, hy = self.half_size
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        return local @ rot.T + self.center

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance from points to this obstacle's footprint on the floor plane.

        Args:
            points: (n, 2) or (2,) [m] world x, y.

        Returns:
            (n,) or scalar [m]: distance to the footprint (box rectangle or disc of radius
            ``half_size[0]``), negative inside.
        """
        p = np.asarray(points, dtype=float)
        d = p - self.center
        if self.kind == "box":
            c, s = math.cos(self.yaw), math.sin(self.yaw)
            local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
            q = np.abs(local) - self.half_size
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
            inside = np.minimum(np.max(q, axis=-1), 0.0)
            return outside + inside
        return np.linalg.norm(d, axis=-1) - self.half_size[0]


@dataclass(frozen=True)
class RobotParams:
    """Nominal robot parameters, read from the compiled model by name (never literals).

    Attributes:
        wheel_radius: [m] driven-wheel radius.
        track: [m] distance between the two driven wheels' contact points.
        footprint_radius: [m] radius of the circle around the base centre that covers the
            whole robot footprint (used to inflate obstacles).
        wheel_speed_max: [rad/s] actuator velocity limit of each wheel.
        v_max: [m/s] top forward speed.
        w_max: [rad/s] top yaw rate.
        a_max: [m/s^2] linear acceleration limit used by planning and control.
        alpha_max: [rad/s^2] yaw acceleration limit used by planning and control.
    """

    wheel_radius: float
    track: float
    footprint_radius: float
    wheel_speed_max: float
    v_max: float
    w_max: float
    a_max: float
    alpha_max: float


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario.

    Attributes:
        name: scenario name (file stem).
        path: absolute path of the MJCF file.
        model: compiled nominal ``mujoco.MjModel`` (never mutate: mismatch works on a copy).
        obstacles: static obstacles in the world frame.
        start: (3,) [m, m, rad] start pose x, y, yaw.
        goal: (2,) [m] goal position.
        bounds: (4,) [m] workspace ``xmin, ymin, xmax, ymax`` (the floor rectangle).
        robot: nominal robot parameters.
    """

    name: str
    path: Path
    model: mujoco.MjModel = field(repr=False)
    obstacles: tuple[Obstacle, ...]
    start: np.ndarray
    goal: np.ndarray
    bounds: np.ndarray
    robot: RobotParams




# ----------------------------------------------------------------------------------------
# Robot parameters, read from the compiled model by name.


def _named(model: mujoco.MjModel, kind: str, name: str) -> int:
    """Id of the named element of ``kind`` ("geom", "body", "joint", "actuator", "numeric")."""
    try:
        return int(getattr(model, kind)(name).id)
    except KeyError:
        raise ScenarioError(
            f"robot model: no {kind} named {name!r} (the robot must follow models/diff_drive.xml)"
        ) from None


def _kinematics_at_qpos0(model: mujoco.MjModel) -> mujoco.MjData:
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return data


def robot_body_ids(model: mujoco.MjModel) -> np.ndarray:
    """Ids of the robot's bodies: ``base`` and everything below it. Shape (n_bodies,) int."""
    base = _named(model, "body", ROBOT_BASE)
    return np.flatnonzero(model.body_rootid == base)


def robot_geom_ids(model: mujoco.MjModel, colliding_only: bool = True) -> np.ndarray:
    """Ids of the robot's geoms (geoms of :func:`robot_body_ids`). Shape (n,) int.

    Args:
        colliding_only: keep only geoms with a nonzero contype or conaffinity.
    """
    bodies = robot_body_ids(model)
    mask = np.isin(model.geom_bodyid, bodies)
    if colliding_only:
        mask &= (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    return np.flatnonzero(mask)


def robot_params(model: mujoco.MjModel) -> RobotParams:
    """Nominal robot parameters read from a compiled model by name.

    - ``wheel_radius`` [m]: mean ``size[0]`` of geoms ``left_wheel`` / ``right_wheel``.
    - ``track`` [m]: lateral distance (in the base frame) between bodies ``left_wheel`` and
      ``right_wheel`` at the model's reference configuration.
    - ``footprint_radius`` [m]: the largest horizontal distance from the base origin of any
      corner of any colliding robot geom's bounding box (``geom_aabb``), so the circle covers
      the whole robot (conservative for round geoms).
    - ``wheel_speed_max`` [rad/s]: the smallest ``|ctrlrange|`` bound of the two wheel
      actuators (which must be control-limited).
    - ``v_max = wheel_speed_max * wheel_radius`` [m/s].
    - ``w_max = min(w_cap, 2 v_max / track)`` [rad/s]: ``2 v_max / track`` is the spin-in-place
      limit of the wheels; ``w_cap`` (custom numeric ``robot_limits[2]``) caps it at a rate the
      controllers can use. The wheels bound the pair jointly:
      ``|v| + |w| track / 2 <= v_max``; the plant scales commands outside that diamond.
    - ``a_max`` [m/s^2], ``alpha_max`` [rad/s^2]: custom numeric ``robot_limits[0:2]``.

    Args:
        model: a compiled model containing the robot of ``models/diff_drive.xml``.

    Raises:
        ScenarioError: a required named element is missing or a value is invalid
            (message starts with ``robot model:``).
    """
    radii = [float(model.geom_size[_named(model, "geom", n), 0]) for n in WHEEL_NAMES]
    wheel_radius = 0.5 * (radii[0] + radii[1])
    base = _named(model, "body", ROBOT_BASE)
    wheel_bodies = [_named(model, "body", n) for n in WHEEL_NAMES]
    acts = [_named(model, "actuator", n) for n in WHEEL_NAMES]
    lim_id = _named(model, "numeric", ROBOT_LIMITS)

    data = _kinematics_at_qpos0(model)
    rot = data.xmat[base].reshape(3, 3)
    origin = data.xpos[base]
    y_wheels = [float((rot.T @ (data.xpos[b] - origin))[1]) for b in wheel_bodies]
    track = abs(y_wheels[0] - y_wheels[1])

    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    footprint = 0.0
    for g in robot_geom_ids(model):
        aabb = model.geom_aabb[g]
        local = aabb[:3] + corners * aabb[3:]
        world = local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        in_base = (world - origin) @ rot
        footprint = max(footprint, float(np.max(np.hypot(in_base[:, 0], in_base[:, 1]))))

    for a, name in zip(acts, WHEEL_NAMES):
        if not model.actuator_ctrllimited[a]:
            raise ScenarioError(f"robot model: actuator {name!r} needs a ctrlrange (the wheel speed limit)")
    wheel_speed_max = float(min(np.min(np.abs(model.actuator_ctrlrange[a])) for a in acts))

    adr, size = int(model.numeric_adr[lim_id]), int(model.numeric_size[lim_id])
    if size != 3:
        raise ScenarioError(
            f"robot model: numeric {ROBOT_LIMITS!r} needs 3 values (a_max alpha_max w_cap), got {size}"
        )
    a_max, alpha_max, w_cap = (float(v) for v in model.numeric_data[adr : adr + 3])
    values = {"wheel_radius": wheel_radius, "track": track, "footprint_radius": footprint,
              "wheel_speed_max": wheel_speed_max, "a_max": a_max, "alpha_max": alpha_max, "w_cap": w_cap}
    values["v_max"] = wheel_speed_max * wheel_radius
    values["mass"] = float(model.body_subtreemass[base])
    for key, val in values.items():
        if not (math.isfinite(val) and val > 0):
            raise ScenarioError(f"robot model: {key} must be a finite number > 0, got {val}")
        low, high, unit, why = ROBOT_RANGES[key]
        if not low <= val <= high:
            raise ScenarioError(
                f"robot model: {key} = {val:.6g} {unit} is outside the physical range [{low:g}, {high:g}] {unit} "
                f"({why}); {_SOURCE[key]}"
            )
    v_max = values["v_max"]
    return RobotParams(
        wheel_radius=wheel_radius,
        track=track,
        footprint_radius=footprint,
        wheel_speed_max=wheel_speed_max,
        v_max=v_max,
        w_max=min(w_cap, 2.0 * v_max / track),
        a_max=a_max,
        alpha_max=alpha_max,
    )


#: Where each checked robot value comes from in the MJCF (for the error message).
_SOURCE = {
    "wheel_radius": "the wheel geoms' size[0]",
    "track": "the lateral distance of the wheel bodies",
    "footprint_radius": "the robot's colliding geoms",
    "wheel_speed_max": "the wheel actuators' ctrlrange",
    "v_max": "wheel_speed_max (ctrlrange) x wheel_radius",
    "a_max": f"custom numeric {ROBOT_LIMITS!r}[0]",
    "alpha_max": f"custom numeric {ROBOT_LIMITS!r}[1]",
    "w_cap": f"custom numeric {ROBOT_LIMITS!r}[2]",
    "mass": f"the masses of body {ROBOT_BASE!r} and its children",
}


def _check_finite_elements(model: mujoco.MjModel) -> None:
    """Every geom's position, size and orientation and every body's position and orientation is finite.

    Raises:
        ScenarioError: naming the element and the attribute (NaN or inf in the file).
    """
    checks = (
        ("geom", model.ngeom, _geom_name, (("pos", model.geom_pos), ("size", model.geom_size),
                                           ("orientation (quat/euler/axisangle/zaxis/xyaxes)", model.geom_quat))),
        ("body", model.nbody, _body_name, (("pos", model.body_pos),
                                           ("orientation (quat/euler/axisangle/zaxis/xyaxes)", model.body_quat))),
    )
    for kind, count, name_of, fields in checks:
        for attr, values in fields:
            bad = np.flatnonzero(~np.all(np.isfinite(values[:count]), axis=1))
            if bad.size:
                k = int(bad[0])
                raise ScenarioError(
                    f"{kind} {name_of(model, k)!r}: {attr} must be finite numbers, got "
                    f"{np.asarray(values[k]).tolist()} (NaN or inf in the file)"
                )


def check_timestep(scenario: "Scenario", control_period_s: float) -> int:
    """Check the scenario's ``<option timestep>`` against the control period; the physics steps per period.

    Args:
        scenario: a loaded scenario (its nominal model's timestep is checked).
        control_period_s: [s] the controller's period ``dt`` (> 0).

    Returns:
        ``round(control_period_s / timestep)``, within :data:`STEPS_PER_PERIOD`.

    Raises:
        ScenarioError: the timestep is not finite, not > 0, or divides the period into fewer than
            10 or more than 1000 steps (message: the file, then ``<option timestep>``).
    """
    ts = float(scenario.model.opt.timestep)
    lo, hi = STEPS_PER_PERIOD
    rule = (f"expected a finite number in [{control_period_s / hi:.3g}, {control_period_s / lo:.3g}] s "
            f"({lo} to {hi} physics steps per {control_period_s:g} s control period; the robot's default is 0.002 s)")
    if not (math.isfinite(ts) and ts > 0):
        raise ScenarioError(f"{scenario.path}: <option timestep>: {rule}, got {ts!r}")
    steps = control_period_s / ts
    if not lo <= steps <= hi:
        raise ScenarioError(f"{scenario.path}: <option timestep>: {rule}, got {ts:g} s ({steps:.3g} steps per period)")
    return int(math.floor(steps + 0.5))


def floor_geom_id(model: mujoco.MjModel) -> int:
    """Id of the scenario's floor: the only static, colliding ``plane`` geom.

    Raises:
        ScenarioError: no such plane, or more than one.
    """
    static = _static_geoms(model)
    planes = [
        g for g in static
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE and (model.geom_contype[g] or model.geom_conaffinity[g])
    ]
    if not planes:
        raise ScenarioError('no floor plane: add <geom name="floor" type="plane" pos="x y 0" size="hx hy 0.1"/>')
    if len(planes) > 1:
        names = ", ".join(repr(_geom_name(model, g)) for g in planes)
        raise ScenarioError(f"more than one plane geom ({names}); exactly one floor plane is supported")
    return planes[0]


def robot_qpos(model: mujoco.MjModel, pose: np.ndarray) -> np.ndarray:
    """A full ``qpos`` with the robot at ``pose``, wheels resting on the floor.

    The base height is the floor height plus the wheel radius minus the wheel bodies' height
    in the base frame (both read from ``model``, so a mismatched model rests correctly).
    Every other coordinate keeps its ``qpos0`` value.

    Args:
        model: compiled scenario model (nominal or a modified copy).
        pose: (3,) [m, m, rad] x, y, yaw of the base origin.

    Returns:
        (model.nq,) qpos.
    """
    pose = np.asarray(pose, dtype=float).reshape(3)
    base = _named(model, "body", ROBOT_BASE)
    jnt = int(model.body_jntadr[base])
    if model.body_jntnum[base] < 1 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise ScenarioError(f"robot model: body {ROBOT_BASE!r} needs a free joint")
    floor = floor_geom_id(model)
    r = float(np.mean([model.geom_size[_named(model, "geom", n), 0] for n in WHEEL_NAMES]))
    data = _kinematics_at_qpos0(model)
    rot = data.xmat[base].reshape(3, 3)
    z_wheel = float(np.mean([(rot.T @ (data.xpos[_named(model, "body", n)] - data.xpos[base]))[2]
                             for n in WHEEL_NAMES]))
    qpos = model.qpos0.copy()
    adr = int(model.jnt_qposadr[jnt])
    qpos[adr : adr + 3] = (pose[0], pose[1], float(model.geom_pos[floor, 2]) + r - z_wheel)
    qpos[adr + 3 : adr + 7] = (math.cos(pose[2] / 2), 0.0, 0.0, math.sin(pose[2] / 2))
    return qpos


def initial_qpos(scenario: Scenario, yaw: float | None = None) -> np.ndarray:
    """``qpos`` (model.nq,) with the robot at the scenario's start, wheels on the floor.

    Args:
        scenario: a loaded scenario.
        yaw: [rad] start yaw; ``None`` uses ``scenario.start[2]``.
    """
    pose = np.array(scenario.start, dtype=float)
    if yaw is not None:
        pose[2] = float(yaw)
    return robot_qpos(scenario.model, pose)


# ----------------------------------------------------------------------------------------
# Loading.


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    return model.geom(g).name or f"geom_{g}"


def _body_name(model: mujoco.MjModel, b: int) -> str:
    return model.body(b).name or f"body_{b}"


def _static_geoms(model: mujoco.MjModel) -> list[int]:
    """Geoms of the world body and of bodies welded to it (no joints up the tree, not mocap)."""
    static_bodies = {b for b in range(model.nbody) if model.body_weldid[b] == 0 and model.body_mocapid[b] < 0}
    return [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in static_bodies]


def resolve_scenario_path(spec: str | Path) -> Path:
    """The MJCF file a scenario spec names: an existing path, else a built-in name.

    Raises:
        ScenarioError: neither an existing file nor a built-in name.
    """
    if not str(spec).strip():
        raise ScenarioError(
            f"scenario argument is empty ({str(spec)!r}): give a path to an MJCF file or a built-in name "
            f"({', '.join(builtin_scenarios())})"
        )
    path = Path(spec).expanduser()
    if path.is_file():
        return path.resolve()
    if path.exists():
        raise ScenarioError(f"{path}: not a file")
    name = str(spec)
    if "/" not in name and "\\" not in name and not name.endswith(".xml"):
        candidate = scenarios_dir() / f"{name}.xml"
        if candidate.is_file():
            return candidate.resolve()
        raise ScenarioError(
            f"{name}: no such file and not a built-in scenario (built-ins: {', '.join(builtin_scenarios())})"
        )
    raise ScenarioError(f"{path}: no such file")


def _one_line(message: str) -> str:
    return "; ".join(part.strip() for part in str(message).strip().splitlines() if part.strip())


_OPEN_ERROR = re.compile(r"Error opening file '([^']*)'")


def _robot_include(message: str) -> dict[str, bytes] | None:
    """If a compile error is a missing ``...diff_drive.xml`` include, the packaged robot for it."""
    match = _OPEN_ERROR.search(message)
    if match and Path(match.group(1)).name == robot_model_path().name:
        return {match.group(1): robot_model_path().read_bytes()}
    return None


def _compile_error(path: Path, message: str) -> ScenarioError:
    text = _one_line(message)
    match = _OPEN_ERROR.search(message)
    if match:
        return ScenarioError(
            f"{path}: cannot open included file {match.group(1)!r} ({text}); include the robot by "
            f'absolute path (<include file="{robot_model_path()}"/>) or as <include file="diff_drive.xml"/>'
        )
    return ScenarioError(f"{path}: not a valid MJCF model: {text}")


def compile_scenario_model(path: Path) -> mujoco.MjModel:
    """Compile a scenario file, supplying the packaged robot for a missing ``diff_drive.xml`` include.

    Raises:
        ScenarioError: one line naming the file and MuJoCo's (condensed) message.
    """
    capture_mujoco_warnings()
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        first = str(err)
    assets = _robot_include(first)
    if assets is None:
        raise _compile_error(path, first)
    try:
        return mujoco.MjModel.from_xml_path(str(path), assets=assets)
    except ValueError as err:
        raise _compile_error(path, str(err)) from None


def scenario_spec(scenario: Scenario | str | Path) -> mujoco.MjSpec:
    """A fresh, editable ``mujoco.MjSpec`` of a scenario file, with the same include rule as loading.

    Use it to build modified model copies (mismatch) without touching ``scenario.model``.
    """
    path = scenario.path if isinstance(scenario, Scenario) else resolve_scenario_path(scenario)
    capture_mujoco_warnings()
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as err:
        first = str(err)
    include = _robot_include(first)
    if include is None:
        raise _compile_error(path, first)
    try:
        return mujoco.MjSpec.from_file(str(path), include=include)
    except ValueError as err:
        raise _compile_error(path, str(err)) from None


def _numeric(model: mujoco.MjModel, name: str, size: int, fmt: str) -> np.ndarray:
    try:
        nid = model.numeric(name).id
    except KeyError:
        raise ScenarioError(f'missing {name}: add <custom><numeric name="{name}" data="{fmt}"/></custom>') from None
    got = int(model.numeric_size[nid])
    if got != size:
        raise ScenarioError(f"{name} must have {size} values ({fmt}), got {got}")
    adr = int(model.numeric_adr[nid])
    values = np.array(model.numeric_data[adr : adr + size], dtype=float)
    if not np.all(np.isfinite(values)):
        raise ScenarioError(f"{name} must be finite, got {values.tolist()}")
    return values


def _workspace(model: mujoco.MjModel, data: mujoco.MjData, floor: int) -> np.ndarray:
    name = _geom_name(model, floor)
    size = model.geom_size[floor]
    if not (np.all(np.isfinite(size[:2])) and size[0] > 0 and size[1] > 0):
        # MuJoCo reads a plane size of 0 as infinite; negative and non-finite sizes are plain errors.
        what = ("a non-finite size" if not np.all(np.isfinite(size[:2]))
                else "a negative size" if np.any(size[:2] < 0) else "infinite size (0 means infinite in MuJoCo)")
        raise ScenarioError(
            f"floor plane {name!r} has {what} {size[:2].tolist()}; set size=\"hx hy 0.1\" with finite hx, hy > 0 "
            "[m] (half extents) to define the workspace"
        )
    rot = data.geom_xmat[floor].reshape(3, 3)
    if not np.allclose(rot, np.eye(3), atol=1e-9):
        raise ScenarioError(f"floor plane {name!r} must be horizontal and axis-aligned (no rotation)")
    c = data.geom_xpos[floor]
    return np.array([c[0] - size[0], c[1] - size[1], c[0] + size[0], c[1] + size[1]], dtype=float)


_GEOM_TYPE_NAMES = {
    int(v): k.removeprefix("mjGEOM_").lower() for k, v in mujoco.mjtGeom.__members__.items() if k.startswith("mjGEOM_")
}


def _obstacle(model: mujoco.MjModel, data: mujoco.MjData, g: int, floor_z: float) -> Obstacle:
    name = _geom_name(model, g)
    gtype = int(model.geom_type[g])
    rot = data.geom_xmat[g].reshape(3, 3)
    center = np.array(data.geom_xpos[g][:2], dtype=float)
    size = model.geom_size[g]
    vertical = np.abs(rot[2, :])  # |cos| between each geom axis and world z
    kind_name = _GEOM_TYPE_NAMES.get(gtype, str(gtype))
    if gtype == mujoco.mjtGeom.mjGEOM_BOX:
        k = int(np.argmax(vertical))
        if vertical[k] < 1.0 - _VERTICAL_TOL:
            raise ScenarioError(f"box {name!r} is tilted: one of its axes must be vertical (rotate about z only)")
        i, j = (a for a in range(3) if a != k)  # the two horizontal axes; yaw from the first
        yaw = math.atan2(rot[1, i], rot[0, i])
        return Obstacle(name, "box", center, yaw, np.array([size[i], size[j]], dtype=float),
                        float(data.geom_xpos[g][2] + size[k] - floor_z), g)
    if gtype in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE):
        if vertical[2] < 1.0 - _VERTICAL_TOL:
            raise ScenarioError(f"{kind_name} {name!r} is tilted: cylinders and capsules must stand upright")
        top = size[1] + (size[0] if gtype == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0)
        kind: ObstacleKind = "cylinder" if gtype == mujoco.mjtGeom.mjGEOM_CYLINDER else "capsule"
        return Obstacle(name, kind, center, 0.0, np.array([size[0], size[0]], dtype=float),
                        float(data.geom_xpos[g][2] + top - floor_z), g)
    raise ScenarioError(
        f"unsupported obstacle geom {name!r} of type {kind_name}: obstacles must be boxes (any yaw), "
        "upright cylinders or upright capsules"
    )


def _can_collide(model: mujoco.MjModel, g: int, robot_geoms: np.ndarray) -> bool:
    ct, ca = int(model.geom_contype[g]), int(model.geom_conaffinity[g])
    return any((ct & int(model.geom_conaffinity[r])) or (int(model.geom_contype[r]) & ca) for r in robot_geoms)


def _check_free(what: str, point: np.ndarray, bounds: np.ndarray, obstacles: tuple[Obstacle, ...],
                robot: RobotParams, margin: float) -> None:
    inflation = robot.footprint_radius + margin
    rule = f"{inflation:.3f} m (footprint radius {robot.footprint_radius:.3f} + margin {margin:.3f})"
    x, y = float(point[0]), float(point[1])
    inner = bounds + np.array([inflation, inflation, -inflation, -inflation])
    if not (inner[0] <= x <= inner[2] and inner[1] <= y <= inner[3]):
        raise ScenarioError(
            f"{what} ({x:.3f}, {y:.3f}) is outside the workspace x [{bounds[0]:.3f}, {bounds[2]:.3f}], "
            f"y [{bounds[1]:.3f}, {bounds[3]:.3f}] shrunk by the inflation radius {rule}"
        )
    for obs in obstacles:
        dist = float(obs.signed_distance(np.array([x, y])))
        if dist < inflation:
            raise ScenarioError(
                f"{what} ({x:.3f}, {y:.3f}) is inside obstacle {obs.name!r} inflated by {rule}: "
                f"distance {dist:.3f} m"
            )


def load_scenario(spec: str | Path, margin: float = 0.05) -> Scenario:
    """Load a scenario from a path to an MJCF file or the name of a built-in one.

    See the module docstring for the rules (robot include, floor, obstacles, start/goal).
    Obstacles come in geom-id order, in the world frame of the model's reference
    configuration (static geoms do not move).

    Args:
        spec: path to an ``.xml`` file, or a built-in name such as ``"u_shape"``.
        margin: [m] extra clearance beyond the footprint radius used to check that start
            and goal are not inside an inflated obstacle (>= 0).

    Raises:
        ScenarioError: one-line message naming the file and what is wrong.
        ValueError: ``margin`` is negative or not finite.
    """
    if not (isinstance(margin, (int, float)) and math.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite number >= 0 [m], got {margin!r}")
    path = resolve_scenario_path(spec)
    model = compile_scenario_model(path)
    try:
        _check_finite_elements(model)
        ts = float(model.opt.timestep)
        if not (math.isfinite(ts) and ts > 0):
            raise ScenarioError(f"<option timestep>: expected a finite number > 0 [s] (the robot's default is 0.002), "
                                f"got {ts!r}")
        robot = robot_params(model)
        robot_qpos(model, np.zeros(3))  # checks the free joint
        data = _kinematics_at_qpos0(model)
        floor = floor_geom_id(model)
        bounds = _workspace(model, data, floor)
        floor_z = float(data.geom_xpos[floor][2])
        robot_geoms = robot_geom_ids(model)
        robot_bodies = set(robot_body_ids(model).tolist())
        static = set(_static_geoms(model))
        obstacles = []
        for g in range(model.ngeom):
            body = int(model.geom_bodyid[g])
            if g == floor or body in robot_bodies or not _can_collide(model, g, robot_geoms):
                continue
            if g not in static:
                raise ScenarioError(
                    f"geom {_geom_name(model, g)!r} is on moving body {_body_name(model, body)!r}: "
                    "obstacles must be static (world body or bodies without joints)"
                )
            obstacles.append(_obstacle(model, data, g, floor_z))
        obstacles_t = tuple(obstacles)
        start = _numeric(model, "start", 3, "x y yaw")
        goal = _numeric(model, "goal", 2, "x y")
        _check_free("start", start[:2], bounds, obstacles_t, robot, float(margin))
        _check_free("goal", goal, bounds, obstacles_t, robot, float(margin))
    except ScenarioError as err:
        raise ScenarioError(f"{path}: {err}") from None
    return Scenario(
        name=path.stem,
        path=path,
        model=model,
        obstacles=obstacles_t,
        start=start,
        goal=goal,
        bounds=bounds,
        robot=robot,
    )
