"""A gymnasium environment over the MuJoCo robot, for training the DQN baseline.

Each episode drives the same MuJoCo differential-drive robot as the runner (through
:class:`~sanav_mj.sim.plant.Plant`) in a *generated* cluttered map, never in one of the
evaluation scenarios: :meth:`NavEnv.reset` draws a map seed from the training range
``[map_seed_start, map_seed_start + n_maps)`` (:func:`training_scenario`: the clutter
generator :mod:`sanav_mj.generate` with a size and density that vary with the seed) and a
random start yaw; the start and goal are the map's own (swapped with probability 1/2) or,
with probability ``random_endpoints``, two random free points of the map.

- Observation: :func:`sanav_mj.control.dqn.build_observation` (the same function the DQN
  controller uses): range rays from MuJoCo ray casts, goal distance and bearing in the robot
  frame, measured (v, w); float32 in [-1, 1].
- Action: an index into the discrete (v, w) table :class:`~sanav_mj.control.dqn.ActionSpec`,
  held for ``dt`` (zero-order hold, as the runner does).
- Reward per step: ``progress * (d_prev - d)`` (progress towards the goal [m]) ``+ time``
  (a small negative constant) ``+ proximity * max(0, 1 - min_ray / proximity_m)`` (a
  small penalty near obstacles); plus ``goal`` on reaching the goal (terminated) and
  ``collision`` on any robot-obstacle contact or on leaving the workspace (terminated).
- Endings: the rules of :mod:`sanav_mj.sim.termination`, the same code and
  :class:`~sanav_mj.sim.termination.TerminationConfig` the runner evaluates with:
  ``collision`` and ``goal`` terminate; ``stuck`` (no progress over the window; without a
  planner the progress is the reduction of the straight-line distance to the goal, as for
  the DQN controller in the runner) and ``timeout`` (``ceil(time_limit_s / dt)`` steps)
  truncate. The environment adds one rule of its own, ``out_of_bounds`` (the footprint
  leaves the workspace; terminated, with the collision reward) between ``collision`` and
  ``goal``: the generated maps have no walls at the workspace edge.
- Rendering: ``render_mode="rgb_array"`` gives a top-down (H, W, 3) uint8 image of the map
  (obstacles dark, robot blue with a heading tick, goal green), drawn with NumPy (no
  OpenGL needed). ``gymnasium.make("sanav_mj/Nav-v0")`` builds the environment once
  ``sanav_mj`` is imported (see :mod:`sanav_mj.envs`).

``info`` at every step has ``reason`` (``"running"``, ``"goal"``, ``"collision"``,
``"out_of_bounds"``, ``"timeout"``, ``"stuck"``) and, at the end of an episode,
``is_success`` (read by stable-baselines3 for its success rate), plus ``map_seed``.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from sanav_mj.control.dqn import ActionSpec, ObservationSpec, build_observation
from sanav_mj.scene import Scenario
from sanav_mj.sim.plant import Plant
from sanav_mj.sim.termination import Termination, TerminationConfig

#: Called with a map seed, returns a training scenario.
MapFactory = Callable[[int], Scenario]


@dataclass(frozen=True)
class RewardConfig:
    """Reward terms (dimensionless reward units).

    Attributes:
        progress: reward per metre of reduction of the distance to the goal.
        goal: bonus on reaching the goal.
        collision: added on contact or leaving the workspace (negative).
        time: added every step (negative: favours short episodes).
        proximity: weight of the near-obstacle penalty ``-proximity * max(0, 1 - r / proximity_m)``
            with ``r`` the shortest ray (0 disables it).
        proximity_m: [m] ray distance below which the proximity penalty starts.
    """

    progress: float = 1.0
    goal: float = 10.0
    collision: float = -10.0
    time: float = -0.01
    proximity: float = 0.05
    proximity_m: float = 0.6

    def __post_init__(self) -> None:
        for name in ("progress", "goal", "collision", "time", "proximity", "proximity_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ValueError(f"RewardConfig.{name}: expected a finite number, got {value!r}")
        if self.progress <= 0 or self.goal < 0:
            raise ValueError(f"RewardConfig.progress/goal: expected progress > 0 and goal >= 0, got {self.progress}, {self.goal}")
        if self.collision > 0 or self.time > 0 or self.proximity < 0:
            raise ValueError("RewardConfig.collision/time: expected <= 0 and proximity >= 0")
        if self.proximity_m <= 0:
            raise ValueError(f"RewardConfig.proximity_m: expected > 0, got {self.proximity_m!r}")


@dataclass(frozen=True)
class NavEnvConfig:
    """Environment settings.

    Attributes:
        dt: [s] control period (zero-order hold of each action).
        termination: goal tolerance, stuck window and progress, time limit: the runner's
            rules and defaults (:class:`~sanav_mj.sim.termination.TerminationConfig`); the
            shipped policy was trained with ``time_limit_s=40`` (400 steps, see
            ``scripts/train_dqn.py``).
        map_seed_start: first training-map seed.
        n_maps: number of training maps (seeds ``map_seed_start .. + n_maps - 1``).
        cache_maps: how many built maps (scenario + plant) are kept in memory (LRU).
        swap_start_goal: with probability 1/2 start at the map's goal and drive to its start.
        random_endpoints: probability that an episode uses a random free start and goal in the
            map instead of the map's own (shorter, more varied episodes).
        endpoint_margin_m: [m] random endpoints keep the footprint this far from obstacles
            and the workspace edge.
        min_goal_distance_m: [m] smallest start-goal distance of random endpoints.
        obs: observation normalisation (shared with the controller).
        actions: discrete action set (shared with the controller).
        reward: reward terms.
    """

    dt: float = 0.1
    termination: TerminationConfig = field(default_factory=TerminationConfig)
    map_seed_start: int = 100_000
    n_maps: int = 1000
    cache_maps: int = 1000
    swap_start_goal: bool = True
    random_endpoints: float = 0.5
    endpoint_margin_m: float = 0.15
    min_goal_distance_m: float = 1.0
    obs: ObservationSpec = field(default_factory=ObservationSpec)
    actions: ActionSpec = field(default_factory=ActionSpec)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        if not (isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"NavEnvConfig.dt: expected a finite number > 0, got {self.dt!r}")
        if not isinstance(self.termination, TerminationConfig):
            raise ValueError(f"NavEnvConfig.termination: expected a TerminationConfig, got {self.termination!r}")
        for name in ("n_maps", "cache_maps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"NavEnvConfig.{name}: expected an int >= 1, got {value!r}")
        if not isinstance(self.map_seed_start, int) or self.map_seed_start < 0:
            raise ValueError(f"NavEnvConfig.map_seed_start: expected an int >= 0, got {self.map_seed_start!r}")
        if not (0.0 <= self.random_endpoints <= 1.0):
            raise ValueError(f"NavEnvConfig.random_endpoints: expected a probability in [0, 1], got {self.random_endpoints!r}")
        for name in ("endpoint_margin_m", "min_goal_distance_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"NavEnvConfig.{name}: expected a finite number >= 0, got {value!r}")


def training_clutter_config(seed: int):
    """The :class:`~sanav_mj.generate.ClutterConfig` of training map ``seed``.

    Map size, obstacle count and obstacle size vary with the seed (drawn from
    ``default_rng([seed, 1])``): width 6-12 m, height 4-8 m, 0 to about one obstacle per
    4.5 m^2, box half-extents up to 0.6-1.5 m (long walls as in the U/V scenarios).
    """
    from sanav_mj.generate import ClutterConfig

    rng = np.random.default_rng([seed, 1])
    width, height = float(rng.uniform(6.0, 12.0)), float(rng.uniform(4.0, 8.0))
    n = int(rng.integers(0, int(width * height / 4.5) + 1))
    return ClutterConfig(width_m=round(width, 2), height_m=round(height, 2), n_min=n, n_max=n,
                         box_half_max_m=round(float(rng.uniform(0.6, 1.5)), 2))


def training_scenario(seed: int, folder: "str | os.PathLike[str]") -> Scenario:
    """Generated training map ``seed`` (:func:`sanav_mj.generate.generate_scenario` with
    :func:`training_clutter_config`), written to ``folder/train_<seed>.xml`` and loaded."""
    from pathlib import Path

    from sanav_mj.generate import generate_scenario
    from sanav_mj.scene import load_scenario

    path = Path(folder) / f"train_{seed}.xml"
    path.write_text(generate_scenario(seed, training_clutter_config(seed)))
    return load_scenario(path)


class NavEnv(gym.Env):
    """Goal-reaching among obstacles with the MuJoCo robot (see the module docstring).

    Args:
        config: environment settings.
        map_factory: ``f(seed) -> Scenario`` building a training map; default
            :func:`training_scenario` (generated clutter, files in a temporary folder).
        render_mode: None or ``"rgb_array"`` (top-down image, see :meth:`render`).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    #: [px/m] scale of the rendered image
    RENDER_PX_PER_M = 20.0

    def __init__(self, config: NavEnvConfig = NavEnvConfig(), map_factory: MapFactory | None = None,
                 render_mode: str | None = None) -> None:
        super().__init__()
        if not isinstance(config, NavEnvConfig):
            raise ValueError(f"config: expected a NavEnvConfig, got {config!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: expected None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.config = config
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1.0 / config.dt)}
        self._tmp: tempfile.TemporaryDirectory | None = None
        if map_factory is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="sanav_nav_env_")
            folder = self._tmp.name
            map_factory = lambda seed: training_scenario(seed, folder)  # noqa: E731
        self._factory = map_factory
        self._table = config.actions.table()
        self.action_space = gym.spaces.Discrete(config.actions.n)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(config.obs.size,), dtype=np.float32)
        self._maps: OrderedDict[int, Plant] = OrderedDict()
        self._plant: Plant | None = None
        self._goal = np.zeros(2)
        self._dist = 0.0
        self._steps = 0
        self._rules = Termination(config.termination, config.dt, self._goal)
        self._backgrounds: dict[int, np.ndarray] = {}
        self._ranges = np.zeros(config.obs.n_rays)
        self.map_seed = -1

    # ------------------------------------------------------------------ maps

    def _plant_for(self, seed: int) -> Plant:
        plant = self._maps.get(seed)
        if plant is None:
            scenario = self._factory(seed)
            self.config.actions.check_within(scenario.robot)
            plant = Plant(scenario)
            self._maps[seed] = plant
            while len(self._maps) > self.config.cache_maps:
                self._maps.popitem(last=False)
        else:
            self._maps.move_to_end(seed)
        return plant

    @property
    def plant(self) -> Plant:
        """The plant of the current episode (after :meth:`reset`)."""
        if self._plant is None:
            raise RuntimeError("NavEnv.plant: call reset() first")
        return self._plant

    @property
    def goal(self) -> np.ndarray:
        """(2,) [m] goal of the current episode."""
        return self._goal.copy()

    # ------------------------------------------------------------------ gym API

    def _observe(self) -> np.ndarray:
        p = self.plant
        self._ranges = p.ray_ranges(self.config.obs.n_rays, self.config.obs.ray_range_m)
        return build_observation(self.config.obs, self._ranges, p.pose(), p.body_velocity(), self._goal)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode on a training map.

        Args:
            seed: seeds the environment's generator (map choice, start yaw, start/goal swap).
            options: optional ``{"map_seed": int, "yaw": float, "swap": bool,
                "random_endpoints": bool}`` to pin them.

        Returns:
            ``(observation, info)``.
        """
        super().reset(seed=seed)
        cfg = self.config
        options = options or {}
        rng = self.np_random
        map_seed = int(options.get("map_seed", cfg.map_seed_start + int(rng.integers(cfg.n_maps))))
        yaw = float(options.get("yaw", rng.uniform(-math.pi, math.pi)))
        swap = bool(options.get("swap", cfg.swap_start_goal and bool(rng.integers(2))))
        self.map_seed = map_seed
        self._plant = self._plant_for(map_seed)
        sc = self._plant.scenario
        if swap:
            start_xy, goal = np.asarray(sc.goal, dtype=float), np.asarray(sc.start[:2], dtype=float)
        else:
            start_xy, goal = np.asarray(sc.start[:2], dtype=float), np.asarray(sc.goal, dtype=float)
        use_random = bool(options.get("random_endpoints", rng.random() < cfg.random_endpoints))
        if use_random:
            pair = self._random_endpoints(sc)
            if pair is not None:
                start_xy, goal = pair
        self._goal = goal.copy()
        self._plant.reset(np.array([start_xy[0], start_xy[1], yaw]))
        self._steps = 0
        self._dist = float(np.hypot(*(start_xy - goal)))
        self._rules = Termination(cfg.termination, cfg.dt, goal)
        return self._observe(), {"reason": "running", "map_seed": map_seed}

    def _random_endpoints(self, sc: Scenario) -> tuple[np.ndarray, np.ndarray] | None:
        """A random free (start, goal) pair at least ``min_goal_distance_m`` apart, or None."""
        cfg = self.config
        keep = sc.robot.footprint_radius + cfg.endpoint_margin_m
        lo, hi = sc.bounds[:2] + keep, sc.bounds[2:] - keep
        if np.any(hi <= lo):
            return None
        pts = self.np_random.uniform(lo, hi, size=(64, 2))
        free = np.ones(len(pts), dtype=bool)
        for o in sc.obstacles:
            free &= o.signed_distance(pts) > keep
        pts = pts[free]
        if len(pts) < 2:
            return None
        far = np.flatnonzero(np.hypot(*(pts[1:] - pts[0]).T) >= cfg.min_goal_distance_m)
        if len(far) == 0:
            return None
        return pts[0], pts[1 + far[0]]

    def _out_of_bounds(self, pose: np.ndarray) -> bool:
        xmin, ymin, xmax, ymax = self.plant.scenario.bounds
        r = self.plant.robot.footprint_radius
        return not (xmin + r <= pose[0] <= xmax - r and ymin + r <= pose[1] <= ymax - r)

    def step(self, action):
        """Apply action ``action`` (an index into the action table) for ``dt``.

        Returns:
            ``(observation, reward, terminated, truncated, info)``.
        """
        if not self.action_space.contains(action):
            raise ValueError(f"action: expected an int in [0, {self.action_space.n}), got {action!r}")
        cfg, rw = self.config, self.config.reward
        p = self.plant
        v, w = self._table[int(action)]
        p.set_wheel_command(v, w)
        contacts = p.advance(cfg.dt)
        self._steps += 1
        pose = p.pose()
        dist = float(np.hypot(*(pose[:2] - self._goal)))
        obs = self._observe()
        reward = rw.progress * (self._dist - dist) + rw.time
        if rw.proximity > 0:
            reward -= rw.proximity * max(0.0, 1.0 - float(self._ranges.min()) / rw.proximity_m)
        self._dist = dist
        rules = self._rules
        reason = rules.arrival(pose[:2], max(contacts, p.robot_obstacle_contacts()))
        if reason != "collision" and self._out_of_bounds(pose):  # a collision with the workspace edge
            reason = "out_of_bounds"
        if reason is None:
            reason = rules.stalled(pose[:2], self._steps)
        terminated = reason in ("collision", "out_of_bounds", "goal")
        truncated = reason in ("stuck", "timeout")
        if reason in ("collision", "out_of_bounds"):
            reward += rw.collision
        elif reason == "goal":
            reward += rw.goal
        reason = reason or "running"
        info: dict[str, Any] = {"reason": reason, "map_seed": self.map_seed}
        if terminated or truncated:
            info["is_success"] = reason == "goal"
        return obs, float(reward), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """The current state as a top-down image when ``render_mode == "rgb_array"``, else None.

        Returns:
            (H, W, 3) uint8, ``RENDER_PX_PER_M`` pixels per metre over the workspace (row 0 at
            the top, ``ymax``): free floor light grey, obstacles dark grey, the goal tolerance
            disc green, the robot's footprint disc blue with a white tick along its heading.
        """
        if self.render_mode is None:
            return None
        p = self.plant
        xs, ys = self._pixel_centres(p.scenario.bounds)
        key = id(p)
        img = self._backgrounds.get(key)
        if img is None:
            free = np.ones(xs.shape, dtype=bool)
            pts = np.column_stack([xs.ravel(), ys.ravel()])
            for o in p.scenario.obstacles:
                free &= (o.signed_distance(pts) > 0).reshape(xs.shape)
            img = np.where(free[..., None], np.uint8(225), np.uint8(60)).repeat(3, axis=2).astype(np.uint8)
            self._backgrounds = {key: img}
        img = img.copy()
        goal = np.hypot(xs - self._goal[0], ys - self._goal[1]) <= self.config.termination.goal_tolerance_m
        img[goal] = (40, 170, 60)
        x, y, yaw = p.pose()
        r = p.robot.footprint_radius
        img[np.hypot(xs - x, ys - y) <= r] = (40, 90, 200)
        u = (xs - x) * math.cos(yaw) + (ys - y) * math.sin(yaw)
        n = -(xs - x) * math.sin(yaw) + (ys - y) * math.cos(yaw)
        img[(u >= 0) & (u <= r) & (np.abs(n) <= 0.5 / self.RENDER_PX_PER_M + 0.02)] = (255, 255, 255)
        return img

    def _pixel_centres(self, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) world x and y [m] of the pixel centres (row 0 at ``ymax``)."""
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        k = self.RENDER_PX_PER_M
        w, h = max(1, int(round((xmax - xmin) * k))), max(1, int(round((ymax - ymin) * k)))
        cx = xmin + (np.arange(w) + 0.5) * (xmax - xmin) / w
        cy = ymax - (np.arange(h) + 0.5) * (ymax - ymin) / h
        return np.meshgrid(cx, cy)

    def close(self) -> None:
        """Release the cached maps and the temporary folder of generated maps (idempotent)."""
        self._maps.clear()
        self._backgrounds.clear()
        self._plant = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        super().close()


# ---------------------------------------------------------------------- training


@dataclass(frozen=True)
class TrainConfig:
    """stable-baselines3 DQN hyper-parameters (MLP Q-network).

    Attributes:
        total_steps: environment steps of training.
        learning_rate: Adam step size.
        buffer_size: replay-buffer capacity [transitions].
        learning_starts: steps of pure exploration before the first gradient step.
        batch_size: transitions per gradient step.
        gamma: discount factor per step.
        train_freq: environment steps between gradient updates.
        gradient_steps: gradient steps per update.
        target_update_interval: environment steps between target-network copies.
        exploration_fraction: fraction of ``total_steps`` over which epsilon decays linearly.
        exploration_initial_eps, exploration_final_eps: epsilon at the start / end of the decay.
        max_grad_norm: gradient-norm clip.
        net_arch: hidden layer widths.
        torch_threads: torch intra-op threads (1 keeps runs reproducible and the machine shared).
    """

    total_steps: int = 400_000
    learning_rate: float = 5e-4
    buffer_size: int = 200_000
    learning_starts: int = 5_000
    batch_size: int = 128
    gamma: float = 0.99
    train_freq: int = 4
    gradient_steps: int = 1
    target_update_interval: int = 2_000
    exploration_fraction: float = 0.2
    exploration_initial_eps: float = 1.0
    exploration_final_eps: float = 0.05
    max_grad_norm: float = 10.0
    net_arch: tuple[int, ...] = (128, 128)
    torch_threads: int = 1

    def __post_init__(self) -> None:
        for name in ("total_steps", "buffer_size", "batch_size", "train_freq", "gradient_steps",
                     "target_update_interval", "torch_threads"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"TrainConfig.{name}: expected an int >= 1, got {value!r}")
        if not isinstance(self.learning_starts, int) or self.learning_starts < 0:
            raise ValueError(f"TrainConfig.learning_starts: expected an int >= 0, got {self.learning_starts!r}")
        if not (isinstance(self.learning_rate, (int, float)) and 0 < self.learning_rate < 1):
            raise ValueError(f"TrainConfig.learning_rate: expected 0 < lr < 1, got {self.learning_rate!r}")
        if not (0 < self.gamma <= 1):
            raise ValueError(f"TrainConfig.gamma: expected 0 < gamma <= 1, got {self.gamma!r}")
        for name in ("exploration_fraction", "exploration_initial_eps", "exploration_final_eps"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value <= 1):
                raise ValueError(f"TrainConfig.{name}: expected a number in [0, 1], got {value!r}")
        if not (self.max_grad_norm > 0):
            raise ValueError(f"TrainConfig.max_grad_norm: expected > 0, got {self.max_grad_norm!r}")
        if not self.net_arch or not all(isinstance(n, int) and n >= 1 for n in self.net_arch):
            raise ValueError(f"TrainConfig.net_arch: expected a non-empty tuple of ints >= 1, got {self.net_arch!r}")


@dataclass
class TrainingLog:
    """What happened during training.

    Attributes:
        episodes: per finished episode ``(end_step, return, length, success, reason, map_seed)``.
        losses: per gradient update ``(step, mean TD (Huber) loss of that update)``.
        wall_time_s: [s] wall time of ``learn`` (including the checkpoint evaluations).
        evaluations: per checkpoint evaluation ``(step, greedy success rate)``.
        best_step: step of the checkpoint with the highest greedy success rate (latest on a
            tie), or -1 without evaluations.
        best_state: that checkpoint's Q-network ``state_dict`` (torch tensors), or None.
        eval_wall_time_s: [s] part of ``wall_time_s`` spent in checkpoint evaluations.
    """

    episodes: list[tuple[int, float, int, bool, str, int]] = field(default_factory=list)
    losses: list[tuple[int, float]] = field(default_factory=list)
    wall_time_s: float = 0.0
    evaluations: list[tuple[int, float]] = field(default_factory=list)
    best_step: int = -1
    best_state: Any = field(default=None, repr=False)
    eval_wall_time_s: float = 0.0

    def loss_array(self) -> np.ndarray:
        """(U, 2) [step, loss] of every gradient update."""
        return np.asarray(self.losses, dtype=float).reshape(-1, 2)

    def episode_array(self) -> np.ndarray:
        """(E, 4) [end_step, return, length, success] of every finished episode."""
        return np.asarray([e[:4] for e in self.episodes], dtype=float).reshape(-1, 4)


def train_dqn(
    env: NavEnv,
    config: TrainConfig,
    seed: int,
    progress: Callable[[int, TrainingLog], None] | None = None,
    eval_env: NavEnv | None = None,
    eval_every: int = 25_000,
    eval_start: int = 100_000,
    eval_episodes: int = 60,
):
    """Train a stable-baselines3 DQN (MLP) on ``env``; needs the ``rl`` extra (torch, SB3).

    Deterministic for a given seed, config, environment and library versions on one machine
    (torch on CPU with ``torch_threads`` threads).

    Args:
        env: the training environment (its maps are generated, never the evaluation ones).
        config: hyper-parameters.
        seed: seeds SB3 (network init, exploration, replay sampling) and the environment.
        progress: optional ``f(step, log)`` called every 1000 environment steps (the edge
            hook for a progress bar; this function itself never prints).
        eval_env: optional validation environment (held-out generated maps). From step
            ``eval_start`` on, every ``eval_every`` steps and at the end, the greedy policy
            runs ``eval_episodes`` episodes there (the same episodes each time: the reset is
            seeded with 0) and the best checkpoint is kept in the log (DQN's greedy policy
            is not monotone in training time). The evaluations use their own environment
            and random generator, so they do not change the training trajectory.

    Returns:
        ``(model, log)``: the trained SB3 ``DQN`` model and the :class:`TrainingLog`.
    """
    import time

    import torch
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(config.torch_threads)
    log = TrainingLog()

    class _LoggedDQN(DQN):
        def train(self, gradient_steps: int, batch_size: int = 100) -> None:
            super().train(gradient_steps, batch_size)
            log.losses.append((int(self.num_timesteps), float(self.logger.name_to_value["train/loss"])))

    class _Episodes(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self._ret = 0.0
            self._len = 0

        def _on_step(self) -> bool:
            self._ret += float(self.locals["rewards"][0])
            self._len += 1
            if self.locals["dones"][0]:
                info = self.locals["infos"][0]
                log.episodes.append((int(self.num_timesteps), self._ret, self._len,
                                     bool(info.get("is_success", False)), str(info.get("reason", "")),
                                     int(info.get("map_seed", -1))))
                self._ret, self._len = 0.0, 0
            if progress is not None and self.num_timesteps % 1000 == 0:
                progress(int(self.num_timesteps), log)
            n = self.num_timesteps
            if eval_env is not None and n >= eval_start and ((n - eval_start) % eval_every == 0
                                                             or n == config.total_steps):
                _checkpoint(self.model, n)
            return True

    def _checkpoint(model, step: int) -> None:
        import copy

        from sanav_mj.control.dqn import qnetwork_from_sb3

        t = time.perf_counter()
        net = qnetwork_from_sb3(model)
        res = evaluate_greedy(eval_env, lambda o: int(np.argmax(net.q_values(o))), eval_episodes, seed=0)
        log.evaluations.append((step, res["success_rate"]))
        if log.best_step < 0 or res["success_rate"] >= max(r for _, r in log.evaluations[:-1] or [(0, -1.0)]):
            log.best_step = step
            log.best_state = copy.deepcopy(model.q_net.state_dict())
        log.eval_wall_time_s += time.perf_counter() - t

    model = _LoggedDQN(
        "MlpPolicy",
        env,
        learning_rate=config.learning_rate,
        buffer_size=config.buffer_size,
        learning_starts=config.learning_starts,
        batch_size=config.batch_size,
        gamma=config.gamma,
        train_freq=config.train_freq,
        gradient_steps=config.gradient_steps,
        target_update_interval=config.target_update_interval,
        exploration_fraction=config.exploration_fraction,
        exploration_initial_eps=config.exploration_initial_eps,
        exploration_final_eps=config.exploration_final_eps,
        max_grad_norm=config.max_grad_norm,
        policy_kwargs={"net_arch": list(config.net_arch)},
        seed=seed,
        device="cpu",
        verbose=0,
    )
    t0 = time.perf_counter()
    model.learn(total_timesteps=config.total_steps, callback=_Episodes())
    log.wall_time_s = time.perf_counter() - t0
    return model, log


def evaluate_greedy(
    env: NavEnv,
    act: Callable[[np.ndarray], int],
    episodes: int,
    seed: int,
) -> dict[str, Any]:
    """Run ``episodes`` episodes of a deterministic policy and count the outcomes.

    Args:
        env: the environment (its map range decides which maps are used).
        act: ``f(observation) -> action index`` (e.g. :meth:`sanav_mj.control.dqn.DQNPolicy.act`).
        episodes: number of episodes, >= 1.
        seed: the first reset is seeded with it (map choice, start yaw, swap), the rest follow.

    Returns:
        ``{"episodes", "success_rate", "reasons": {reason: count}, "mean_return",
        "mean_length", "mean_success_length"}`` (lengths in steps).
    """
    if episodes < 1:
        raise ValueError(f"episodes: expected >= 1, got {episodes!r}")
    reasons: dict[str, int] = {}
    returns, lengths, ok_lengths = [], [], []
    obs, _ = env.reset(seed=seed)
    for _ in range(episodes):
        ret, n = 0.0, 0
        while True:
            obs, r, term, trunc, info = env.step(act(obs))
            ret += r
            n += 1
            if term or trunc:
                break
        reasons[info["reason"]] = reasons.get(info["reason"], 0) + 1
        returns.append(ret)
        lengths.append(n)
        if info["reason"] == "goal":
            ok_lengths.append(n)
        obs, _ = env.reset()
    return {
        "episodes": episodes,
        "success_rate": reasons.get("goal", 0) / episodes,
        "reasons": dict(sorted(reasons.items())),
        "mean_return": float(np.mean(returns)),
        "mean_length": float(np.mean(lengths)),
        "mean_success_length": float(np.mean(ok_lengths)) if ok_lengths else float("nan"),
    }
