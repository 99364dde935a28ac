#!/usr/bin/env python
"""Train the DQN baseline on generated training maps and write the shipped policy.

Needs the ``rl`` extra (``pip install torch==2.13.0`` first on CPU-only machines, then
``pip install -e .[rl]``). Writes into ``--out`` (default ``models/dqn``):

    policy.npz       Q-network weights + observation/action spec (NumPy-only inference)
    dqn_sb3.zip      the stable-baselines3 model (without replay buffer), if under 2 MB
    training.json    seed, hyper-parameters, environment config, steps, wall time, metrics
    training.png     training curve: episode return, success rate, TD loss
    episodes.csv     one row per training episode

Example (the shipped policy):  python scripts/train_dqn.py --steps 400000 --seed 0

``--evaluate N`` trains nothing: it runs the policy in ``--out`` on the built-in (evaluation)
scenarios, N seeds each (random initial yaw), through the same harness as ``sanav-mj run``
(:func:`sanav_mj.eval.episode.run_scenario`) and writes ``evaluation.json`` beside it.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from sanav_mj.control.dqn import DEFAULT_POLICY_FILE, DQNPolicy, qnetwork_from_sb3
from sanav_mj.sim.nav_env import NavEnv, NavEnvConfig, TrainConfig, evaluate_greedy, train_dqn
from sanav_mj.sim.termination import TerminationConfig

#: [s] episode time limit of training (400 steps of 0.1 s)
TRAINING_TIME_LIMIT_S = 40.0

#: Map seeds for checkpoint selection during training (disjoint from training and test maps).
SELECTION_MAP_SEED_START = 800_000
#: Held-out map seeds for the post-training check (disjoint from training and selection maps).
VALIDATION_MAP_SEED_START = 900_000
SB3_ZIP_LIMIT_BYTES = 2 * 1024 * 1024


def _rolling(x: np.ndarray, n: int) -> np.ndarray:
    """Trailing mean over up to ``n`` samples, same length as ``x``."""
    if len(x) == 0:
        return x
    c = np.cumsum(np.insert(np.asarray(x, dtype=float), 0, 0.0))
    idx = np.arange(1, len(x) + 1)
    lo = np.maximum(0, idx - n)
    return (c[idx] - c[lo]) / (idx - lo)


def _plot(log, total_steps: int, path: Path, title: str, shipped_step: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = log.episode_array()
    loss = log.loss_array()
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    if len(ep):
        axes[0].plot(ep[:, 0], ep[:, 1], ".", ms=1.5, alpha=0.3, color="tab:blue")
        axes[0].plot(ep[:, 0], _rolling(ep[:, 1], 100), color="tab:blue", label="mean of last 100 episodes")
        axes[1].plot(ep[:, 0], 100 * _rolling(ep[:, 3], 100), color="tab:green",
                     label="training episodes (epsilon-greedy, last 100)")
    if log.evaluations:
        ev = np.asarray(log.evaluations, dtype=float)
        axes[1].plot(ev[:, 0], 100 * ev[:, 1], "o-", color="black", ms=4, label="greedy, selection maps")
        axes[1].legend(loc="lower right", fontsize=8)
    for ax in axes:
        ax.axvline(shipped_step, color="gray", ls="--", lw=1)
    axes[0].set_ylabel("episode return")
    axes[0].legend(loc="lower right")
    axes[1].set_ylabel("success %")
    axes[1].set_ylim(0, 100)
    if len(loss):
        axes[2].plot(loss[:, 0], _rolling(loss[:, 1], 500), color="tab:red")
        axes[2].set_yscale("log")
    axes[2].set_ylabel("TD (Huber) loss\n(mean of last 500 updates)")
    axes[2].set_xlabel("environment steps")
    axes[2].set_xlim(0, total_steps)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def evaluate_builtin(out: Path, runs: int) -> dict:
    """Run the policy ``out/policy.npz`` on every built-in scenario for seeds 0..runs-1."""
    from sanav_mj.control.dqn import DQNController
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import prepare
    from sanav_mj.resources import builtin_scenarios

    result: dict = {"policy": str(out / DEFAULT_POLICY_FILE), "runs_per_scenario": runs, "scenarios": {}}
    for name in builtin_scenarios():
        prep = prepare(name)
        rows = []
        for seed in range(runs):
            ctrl = DQNController.load(out / DEFAULT_POLICY_FILE, prep.scenario.robot, prep.scenario.goal)
            doc = run_scenario(prep, controller="dqn", seed=seed, controller_obj=ctrl).document
            rows.append({k: doc[k] for k in ("seed", "success", "reason", "steps", "sim_time_s", "path_length_m",
                                             "min_clearance_m")} | {"yaw": doc["start"][2],
                                                                     "solve_ms_mean": doc["solve_ms"]["mean"],
                                                                     "solve_ms_max": doc["solve_ms"]["max"]})
        reasons: dict[str, int] = {}
        for r in rows:
            reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
        result["scenarios"][name] = {
            "success_rate": sum(r["success"] for r in rows) / runs,
            "reasons": dict(sorted(reasons.items())),
            "runs": rows,
        }
        print(f"{name:12s} success {100 * result['scenarios'][name]['success_rate']:5.1f} %  {reasons}", flush=True)
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--steps", type=int, default=TrainConfig.total_steps, help="environment steps")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("models/dqn"))
    ap.add_argument("--n-maps", type=int, default=NavEnvConfig.n_maps, help="number of training maps")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--val-episodes", type=int, default=200, help="held-out greedy episodes after training")
    ap.add_argument("--select-episodes", type=int, default=60,
                    help="greedy episodes per checkpoint evaluation (0: ship the final network)")
    ap.add_argument("--select-every", type=int, default=25_000, help="steps between checkpoint evaluations")
    ap.add_argument("--select-start", type=int, default=100_000, help="first checkpoint evaluation")
    ap.add_argument("--measure", type=int, default=0,
                    help="only measure training steps/s over this many steps, write nothing")
    ap.add_argument("--evaluate", type=int, default=0, metavar="N",
                    help="do not train: run the policy in --out on the built-in scenarios, N seeds each")
    args = ap.parse_args(argv)
    if args.evaluate:
        result = evaluate_builtin(args.out, args.evaluate)
        (args.out / "evaluation.json").write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out / 'evaluation.json'}")
        return 0

    import gymnasium
    import mujoco
    import stable_baselines3
    import torch
    from tqdm import tqdm

    # The runner's termination rules (sanav_mj.sim.termination) with 40 s (400-step) episodes:
    # the training maps are 6-12 m wide; the shipped policy was trained this way.
    env_cfg = NavEnvConfig(n_maps=args.n_maps, termination=TerminationConfig(time_limit_s=TRAINING_TIME_LIMIT_S))
    train_cfg = TrainConfig(total_steps=args.measure or args.steps, torch_threads=args.threads)
    if args.measure:
        train_cfg = replace(train_cfg, learning_starts=min(train_cfg.learning_starts, args.measure // 4))
    env = NavEnv(env_cfg)

    bar = tqdm(total=train_cfg.total_steps, unit="step", smoothing=0.05)

    def progress(step: int, log) -> None:
        bar.n = step
        recent = log.episodes[-100:]
        if recent:
            bar.set_postfix(ep=len(log.episodes), ret=f"{np.mean([e[1] for e in recent]):.2f}",
                            succ=f"{np.mean([e[3] for e in recent]):.2f}")
        bar.refresh()

    select_env = None
    if args.select_episodes and not args.measure:
        select_env = NavEnv(replace(env_cfg, map_seed_start=SELECTION_MAP_SEED_START, n_maps=args.select_episodes,
                                    random_endpoints=0.0))
    model, log = train_dqn(env, train_cfg, seed=args.seed, progress=progress, eval_env=select_env,
                           eval_every=args.select_every, eval_start=args.select_start,
                           eval_episodes=args.select_episodes)
    bar.close()
    shipped_step = train_cfg.total_steps
    if log.best_state is not None:
        model.q_net.load_state_dict(log.best_state)
        model.q_net_target.load_state_dict(log.best_state)
        shipped_step = log.best_step
        print(f"checkpoint selection: {log.evaluations}; shipping step {shipped_step}")
    steps_per_s = train_cfg.total_steps / log.wall_time_s
    print(f"trained {train_cfg.total_steps} steps in {log.wall_time_s:.0f} s ({steps_per_s:.0f} steps/s), "
          f"{len(log.episodes)} episodes")
    if args.measure:
        return 0

    # Export and check the NumPy network against torch on random observations.
    net = qnetwork_from_sb3(model)
    rng = np.random.default_rng(args.seed)
    probe = rng.uniform(-1, 1, size=(256, env_cfg.obs.size)).astype(np.float32)
    with torch.no_grad():
        q_torch = model.q_net(torch.as_tensor(probe)).numpy()
    max_diff = float(np.abs(net.q_values(probe) - q_torch).max())
    if max_diff > 1e-4:
        print(f"error: numpy and torch Q-values differ by {max_diff}", file=sys.stderr)
        return 1

    # Held-out check on generated maps the training never saw.
    val_env = NavEnv(replace(env_cfg, map_seed_start=VALIDATION_MAP_SEED_START, n_maps=args.val_episodes,
                             random_endpoints=0.0))
    policy_tmp = DQNPolicy(net, env_cfg.obs, env_cfg.actions, env_cfg.dt)
    validation = evaluate_greedy(val_env, policy_tmp.act, args.val_episodes, seed=args.seed + 1)
    print(f"held-out greedy: {validation}")

    ep = log.episode_array()
    loss = log.loss_array()
    last = ep[-200:]
    final = {
        "episodes": int(len(ep)),
        "last_200_episodes": {
            "mean_return": float(last[:, 1].mean()),
            "success_rate": float(last[:, 3].mean()),
            "reasons": {r: sum(1 for e in log.episodes[-200:] if e[4] == r)
                        for r in sorted({e[4] for e in log.episodes[-200:]})},
        },
        "td_loss_first_1000_updates": float(loss[:1000, 1].mean()),
        "td_loss_last_1000_updates": float(loss[-1000:, 1].mean()),
        "shipped_checkpoint_step": shipped_step,
        "held_out_greedy": validation,
        "numpy_vs_torch_max_abs_q_diff": max_diff,
    }
    info = {
        "seed": args.seed,
        "total_steps": train_cfg.total_steps,
        "wall_time_s": round(log.wall_time_s, 1),
        "steps_per_s": round(steps_per_s, 1),
        "algorithm": "stable-baselines3 DQN, MlpPolicy",
        "hyperparameters": asdict(train_cfg),
        "env": {
            "dt": env_cfg.dt, "max_steps": env_cfg.termination.max_steps(env_cfg.dt),
            "goal_tolerance_m": env_cfg.termination.goal_tolerance_m,
            "stuck_window_s": env_cfg.termination.stuck_window_s,
            "stuck_progress_m": env_cfg.termination.stuck_progress_m,
            "training_map_seeds": [env_cfg.map_seed_start, env_cfg.map_seed_start + env_cfg.n_maps - 1],
            "validation_map_seeds": [VALIDATION_MAP_SEED_START, VALIDATION_MAP_SEED_START + args.val_episodes - 1],
            "swap_start_goal": env_cfg.swap_start_goal, "random_endpoints": env_cfg.random_endpoints,
            "endpoint_margin_m": env_cfg.endpoint_margin_m, "min_goal_distance_m": env_cfg.min_goal_distance_m,
            "maps": "sanav_mj.sim.nav_env.training_scenario (sanav_mj.generate clutter, seed-varied size/density)",
            "obs": asdict(env_cfg.obs), "actions": asdict(env_cfg.actions), "reward": asdict(env_cfg.reward),
        },
        "checkpoint_selection": {
            "rule": "highest greedy success rate on the selection maps (latest on a tie)",
            "selection_map_seeds": [SELECTION_MAP_SEED_START, SELECTION_MAP_SEED_START + args.select_episodes - 1]
            if select_env is not None else None,
            "episodes": args.select_episodes, "every_steps": args.select_every, "start_step": args.select_start,
            "evaluations": [[int(a), float(b)] for a, b in log.evaluations],
            "best_step": shipped_step, "eval_wall_time_s": round(log.eval_wall_time_s, 1),
        },
        "final_metrics": final,
        "versions": {
            "python": platform.python_version(), "torch": torch.__version__,
            "stable_baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__,
            "mujoco": mujoco.__version__, "numpy": np.__version__,
        },
        "machine": f"{platform.machine()}, {__import__('os').cpu_count()} cores",
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
    }

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    DQNPolicy(net, env_cfg.obs, env_cfg.actions, env_cfg.dt, info=info).save(out / DEFAULT_POLICY_FILE)
    zip_path = out / "dqn_sb3.zip"
    model.save(zip_path, exclude=["replay_buffer"])
    if zip_path.stat().st_size > SB3_ZIP_LIMIT_BYTES:
        zip_path.unlink()
        info["sb3_zip"] = "not kept (over 2 MB)"
    (out / "training.json").write_text(json.dumps(info, indent=2) + "\n")
    with open(out / "episodes.csv", "w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(["end_step", "return", "length", "success", "reason", "map_seed"])
        for e in log.episodes:
            wr.writerow([e[0], f"{e[1]:.4f}", e[2], int(e[3]), e[4], e[5]])
    _plot(log, train_cfg.total_steps, out / "training.png",
          f"DQN training (seed {args.seed}, {train_cfg.total_steps} steps, {log.wall_time_s / 60:.0f} min; "
          f"dashed: shipped checkpoint)", shipped_step)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
