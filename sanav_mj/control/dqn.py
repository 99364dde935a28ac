"""The DQN baseline: a learned Q-network choosing among discrete (v, w) commands.

The policy is trained offline (``scripts/train_dqn.py``, stable-baselines3 DQN on the
gymnasium environment :class:`sanav_mj.sim.nav_env.NavEnv`) and shipped as a ``.npz`` of the
Q-network's weights, so inference here needs only NumPy: the controller runs without torch.

What the network sees is built by :func:`build_observation`, the ONE function shared by the
training environment and this controller (``sim`` imports ``control``, never the reverse), so
the two cannot drift apart:

    obs = [ ranges / ray_range_m              (n_rays,)  in [0, 1], ray i at yaw + 2 pi i / n_rays
            min(d, goal_range_m) / goal_range_m          distance to the goal, in [0, 1]
            cos(bearing), sin(bearing)                   goal bearing in the robot frame
            clip(v / v_scale, -1, 1), clip(w / w_scale, -1, 1) ]   measured body velocity

The ray order is whatever ``Plant.ray_ranges`` returns; the environment and the runner both
read the rays from the same plant method, so training and deployment agree by construction.

Actions are the rows of a fixed ``(A, 2)`` table of (v, w) [m/s, rad/s] commands
(:class:`ActionSpec`), including rotation in place (v = 0) and a full stop.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sanav_mj.control.base import Command, Observation
from sanav_mj.scene import RobotParams

#: Format version of the ``.npz`` policy file written by :meth:`DQNPolicy.save`.
POLICY_FORMAT = 1

#: File name of the shipped policy inside ``models/dqn/``.
DEFAULT_POLICY_FILE = "policy.npz"


def _positive(owner: str, name: str, value: Any) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{owner}.{name}: expected a finite number > 0, got {value!r}")


@dataclass(frozen=True)
class ObservationSpec:
    """How raw measurements are normalised into the network input.

    Attributes:
        n_rays: number of range rays (evenly spaced over 360 degrees).
        ray_range_m: [m] maximum ray range; readings are divided by it and clipped to [0, 1].
        goal_range_m: [m] distance normalisation; farther goals read as 1.
        v_scale: [m/s] forward-speed normalisation.
        w_scale: [rad/s] yaw-rate normalisation.
    """

    n_rays: int = 36
    ray_range_m: float = 5.0
    goal_range_m: float = 10.0
    v_scale: float = 1.0
    w_scale: float = 2.0

    def __post_init__(self) -> None:
        if not isinstance(self.n_rays, (int, np.integer)) or isinstance(self.n_rays, bool) or self.n_rays < 1:
            raise ValueError(f"ObservationSpec.n_rays: expected an int >= 1, got {self.n_rays!r}")
        for name in ("ray_range_m", "goal_range_m", "v_scale", "w_scale"):
            _positive("ObservationSpec", name, getattr(self, name))

    @property
    def size(self) -> int:
        """Length of the observation vector, ``n_rays + 5``."""
        return int(self.n_rays) + 5


@dataclass(frozen=True)
class ActionSpec:
    """The discrete action set: every (v, w) pair of ``v_levels x w_levels``.

    Attributes:
        v_levels: [m/s] forward speeds (include 0 for rotation in place and stopping).
        w_levels: [rad/s] yaw rates (include 0 for driving straight).
    """

    v_levels: tuple[float, ...] = (0.0, 0.4, 0.8)
    w_levels: tuple[float, ...] = (-1.5, -0.75, 0.0, 0.75, 1.5)

    def __post_init__(self) -> None:
        for name in ("v_levels", "w_levels"):
            levels = getattr(self, name)
            if not isinstance(levels, tuple) or len(levels) < 1:
                raise ValueError(f"ActionSpec.{name}: expected a non-empty tuple of floats, got {levels!r}")
            if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in levels):
                raise ValueError(f"ActionSpec.{name}: expected finite numbers, got {levels!r}")
            if len(set(levels)) != len(levels):
                raise ValueError(f"ActionSpec.{name}: expected distinct values, got {levels!r}")

    @property
    def n(self) -> int:
        """Number of actions ``len(v_levels) * len(w_levels)``."""
        return len(self.v_levels) * len(self.w_levels)

    def table(self) -> np.ndarray:
        """(A, 2) [m/s, rad/s] the command of each action index, v-major order."""
        return np.array([(v, w) for v in self.v_levels for w in self.w_levels], dtype=float)

    def check_within(self, robot: RobotParams) -> None:
        """Raise ``ValueError`` when a level exceeds the robot's ``v_max`` / ``w_max``."""
        if max(abs(v) for v in self.v_levels) > robot.v_max + 1e-9:
            raise ValueError(f"ActionSpec.v_levels: expected |v| <= robot v_max {robot.v_max}, got {self.v_levels!r}")
        if max(abs(w) for w in self.w_levels) > robot.w_max + 1e-9:
            raise ValueError(f"ActionSpec.w_levels: expected |w| <= robot w_max {robot.w_max}, got {self.w_levels!r}")


def build_observation(
    spec: ObservationSpec,
    ranges: np.ndarray,
    pose: np.ndarray,
    velocity: np.ndarray,
    goal: np.ndarray,
) -> np.ndarray:
    """The network input from raw measurements (shared by the environment and the controller).

    Args:
        spec: the normalisation.
        ranges: (n_rays,) [m] range readings (values beyond ``spec.ray_range_m`` are clipped).
        pose: (3,) [m, m, rad] robot x, y, yaw.
        velocity: (2,) [m/s, rad/s] measured body forward speed and yaw rate.
        goal: (2,) [m] goal position in the world frame.

    Returns:
        (spec.size,) float32 observation, every entry in [-1, 1] (see the module docstring).

    Raises:
        ValueError: ``ranges`` has the wrong length.
    """
    ranges = np.asarray(ranges, dtype=float).reshape(-1)
    if ranges.shape[0] != spec.n_rays:
        raise ValueError(f"ranges: expected {spec.n_rays} rays, got {ranges.shape[0]}")
    pose = np.asarray(pose, dtype=float).reshape(3)
    velocity = np.asarray(velocity, dtype=float).reshape(2)
    goal = np.asarray(goal, dtype=float).reshape(2)
    out = np.empty(spec.size, dtype=np.float32)
    r = np.nan_to_num(ranges / spec.ray_range_m, nan=1.0, posinf=1.0, neginf=0.0)
    out[: spec.n_rays] = np.clip(r, 0.0, 1.0)
    dx, dy = goal - pose[:2]
    dist = math.hypot(dx, dy)
    bearing = math.atan2(dy, dx) - pose[2]
    n = spec.n_rays
    out[n] = min(dist, spec.goal_range_m) / spec.goal_range_m
    out[n + 1] = math.cos(bearing)
    out[n + 2] = math.sin(bearing)
    out[n + 3] = np.clip(velocity[0] / spec.v_scale, -1.0, 1.0)
    out[n + 4] = np.clip(velocity[1] / spec.w_scale, -1.0, 1.0)
    return out


@dataclass(frozen=True)
class QNetwork:
    """A ReLU multilayer perceptron mapping observations to one Q-value per action.

    Attributes:
        weights: per layer, an (n_in, n_out) float array; ``h = relu(h @ W + b)`` on hidden
            layers, no activation on the last one.
        biases: per layer, an (n_out,) float array.
    """

    weights: tuple[np.ndarray, ...] = field(repr=False)
    biases: tuple[np.ndarray, ...] = field(repr=False)

    def __post_init__(self) -> None:
        if len(self.weights) < 1 or len(self.weights) != len(self.biases):
            raise ValueError(
                f"QNetwork.weights/biases: expected the same non-zero number of layers, "
                f"got {len(self.weights)} and {len(self.biases)}"
            )
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            if w.ndim != 2 or b.shape != (w.shape[1],):
                raise ValueError(f"QNetwork layer {i}: expected W (n_in, n_out) and b (n_out,), got {w.shape}, {b.shape}")
            if i > 0 and w.shape[0] != self.weights[i - 1].shape[1]:
                raise ValueError(f"QNetwork layer {i}: expected {self.weights[i - 1].shape[1]} inputs, got {w.shape[0]}")
            if not (np.all(np.isfinite(w)) and np.all(np.isfinite(b))):
                raise ValueError(f"QNetwork layer {i}: expected finite weights")

    @property
    def n_in(self) -> int:
        """Observation size the network expects."""
        return int(self.weights[0].shape[0])

    @property
    def n_out(self) -> int:
        """Number of actions."""
        return int(self.weights[-1].shape[1])

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """Q-values of every action.

        Args:
            obs: (n_in,) or (B, n_in) observations.

        Returns:
            (n_out,) or (B, n_out) Q-values (float32 arithmetic, as the trained network).
        """
        h = np.asarray(obs, dtype=np.float32)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            if i < last:
                np.maximum(h, 0.0, out=h)
        return h


@dataclass(frozen=True)
class DQNPolicy:
    """A trained DQN policy: network, observation normalisation, action table and period.

    Attributes:
        network: the Q-network.
        obs_spec: the observation normalisation used in training.
        actions: the discrete action set used in training (index order = network outputs).
        dt: [s] control period used in training.
        info: free-form training record (seed, hyper-parameters, steps, metrics); JSON-able.
    """

    network: QNetwork
    obs_spec: ObservationSpec
    actions: ActionSpec
    dt: float = 0.1
    info: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        _positive("DQNPolicy", "dt", self.dt)
        if self.network.n_in != self.obs_spec.size:
            raise ValueError(
                f"DQNPolicy.network: expected {self.obs_spec.size} inputs (obs_spec), got {self.network.n_in}"
            )
        if self.network.n_out != self.actions.n:
            raise ValueError(f"DQNPolicy.network: expected {self.actions.n} outputs (actions), got {self.network.n_out}")

    def act(self, obs: np.ndarray) -> int:
        """Greedy action index for one (n_in,) observation (ties go to the lowest index)."""
        return int(np.argmax(self.network.q_values(obs)))

    def save(self, path: str | Path) -> None:
        """Write the policy to a ``.npz`` (no pickled objects; loads with ``allow_pickle=False``)."""
        arrays: dict[str, np.ndarray] = {}
        for i, (w, b) in enumerate(zip(self.network.weights, self.network.biases)):
            arrays[f"W{i}"] = np.asarray(w, dtype=np.float32)
            arrays[f"b{i}"] = np.asarray(b, dtype=np.float32)
        meta = {
            "format": POLICY_FORMAT,
            "n_layers": len(self.network.weights),
            "obs_spec": asdict(self.obs_spec),
            "actions": {"v_levels": list(self.actions.v_levels), "w_levels": list(self.actions.w_levels)},
            "dt": self.dt,
            "info": self.info,
        }
        arrays["meta"] = np.array(json.dumps(meta))
        np.savez(Path(path), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "DQNPolicy":
        """Read a policy written by :meth:`save`.

        Raises:
            ValueError: the file is not a policy of a supported format.
        """
        path = Path(path)
        with np.load(path, allow_pickle=False) as data:
            if "meta" not in data:
                raise ValueError(f"{path}: not a DQN policy file (no 'meta' entry)")
            meta = json.loads(str(data["meta"]))
            if meta.get("format") != POLICY_FORMAT:
                raise ValueError(f"{path}: expected policy format {POLICY_FORMAT}, got {meta.get('format')!r}")
            n = int(meta["n_layers"])
            weights = tuple(np.array(data[f"W{i}"], dtype=np.float32) for i in range(n))
            biases = tuple(np.array(data[f"b{i}"], dtype=np.float32) for i in range(n))
        acts = meta["actions"]
        return cls(
            network=QNetwork(weights, biases),
            obs_spec=ObservationSpec(**meta["obs_spec"]),
            actions=ActionSpec(tuple(float(v) for v in acts["v_levels"]), tuple(float(w) for w in acts["w_levels"])),
            dt=float(meta["dt"]),
            info=meta.get("info", {}),
        )


def qnetwork_from_sb3(model: Any) -> QNetwork:
    """Export the online Q-network of a stable-baselines3 ``DQN`` model to NumPy.

    Expects the default ``MlpPolicy`` (flatten features, ``Linear``/``ReLU`` stack). Needs
    torch only through ``model`` itself; this module never imports torch.

    Raises:
        ValueError: the network is not a plain Linear/ReLU stack.
    """
    weights: list[np.ndarray] = []
    biases: list[np.ndarray] = []
    layers = list(model.q_net.q_net)
    for i, layer in enumerate(layers):
        kind = type(layer).__name__
        if kind == "Linear":
            weights.append(layer.weight.detach().cpu().numpy().astype(np.float32).T.copy())
            biases.append(layer.bias.detach().cpu().numpy().astype(np.float32).copy())
        elif kind == "ReLU":
            if i == len(layers) - 1 or type(layers[i - 1]).__name__ != "Linear":
                raise ValueError(f"qnetwork_from_sb3: unexpected ReLU at layer {i}")
        else:
            raise ValueError(f"qnetwork_from_sb3: expected Linear/ReLU layers, got {kind} at layer {i}")
    if type(layers[-1]).__name__ != "Linear":
        raise ValueError("qnetwork_from_sb3: expected the last layer to be Linear")
    return QNetwork(tuple(weights), tuple(biases))


def default_policy_path() -> Path:
    """Path of the shipped policy, ``models/dqn/policy.npz``."""
    from sanav_mj.resources import models_dir

    return models_dir() / "dqn" / DEFAULT_POLICY_FILE


class DQNController:
    """Greedy DQN policy as a :class:`~sanav_mj.control.base.Controller` (NumPy inference).

    Each step builds the observation from the measured pose, velocity and range rays, runs the
    Q-network forward and applies the (v, w) of the best action. ``Command.solve_ms`` is the
    wall time of observation + forward pass + argmax.
    """

    name = "dqn"
    needs_ranges = True

    def __init__(self, policy: DQNPolicy, robot: RobotParams, goal: np.ndarray) -> None:
        """
        Args:
            policy: the trained policy.
            robot: nominal robot parameters (the action table must lie within its limits).
            goal: (2,) [m] goal position in the world frame.

        Raises:
            ValueError: an action exceeds the robot's limits, or the goal is not finite.
        """
        policy.actions.check_within(robot)
        goal = np.asarray(goal, dtype=float).reshape(2)
        if not np.all(np.isfinite(goal)):
            raise ValueError(f"goal: expected 2 finite numbers, got {goal!r}")
        self.policy = policy
        self.robot = robot
        self.goal = goal
        self.dt = float(policy.dt)
        self._table = policy.actions.table()
        self.last_action: int | None = None

    @classmethod
    def load(cls, path: str | Path, robot: RobotParams, goal: np.ndarray) -> "DQNController":
        """Controller from a policy file written by :meth:`DQNPolicy.save`."""
        return cls(DQNPolicy.load(path), robot, goal)

    @classmethod
    def load_default(cls, robot: RobotParams, goal: np.ndarray) -> "DQNController":
        """Controller running the shipped policy ``models/dqn/policy.npz``."""
        return cls.load(default_policy_path(), robot, goal)

    def reset(self, pose: np.ndarray) -> None:
        """New episode (the policy is memoryless; only the last action is forgotten)."""
        self.last_action = None

    def step(self, obs: Observation) -> Command:
        """Greedy (v, w) for this observation.

        Raises:
            ValueError: ``obs.ranges`` is missing or has the wrong number of rays.
        """
        if obs.ranges is None:
            raise ValueError("obs.ranges: the DQN controller needs range rays (needs_ranges = True), got None")
        t0 = time.perf_counter()
        x = build_observation(self.policy.obs_spec, obs.ranges, obs.pose, obs.velocity, self.goal)
        a = self.policy.act(x)
        solve_ms = (time.perf_counter() - t0) * 1e3
        self.last_action = a
        v, w = self._table[a]
        return Command(v=float(v), w=float(w), solve_ms=solve_ms, status="ok")
