"""Benchmark the SA-MPC solver back-ends on one recorded sequence of optimal-control problems.

1. Record: a kinematic closed loop (exact unicycle plant with 5 % speed / yaw-rate gain
   mismatch) drives SA-MPC, solved tightly by IPOPT, through a synthetic L-shaped corridor
   of three safe areas, a U-shaped one and (unless ``--no-scenarios``) the five built-in
   scenarios after mapping and planning (start yaw from seed 0). The robot parameters are
   those of ``models/diff_drive.xml``. Every problem the controller poses (measured state,
   previous input, reference, stage boxes, J_SA areas, bounds) is recorded with its tight
   optimum.
2. Replay: each back-end solves the same sequence in order, warm-started from its own
   shifted previous solution (primal and multipliers) exactly as the controller does; the
   back-ends take turns problem by problem, so a change of the machine's load hits them
   alike. Wall and CPU time of each ``backend.solve`` call (the Python call included) are
   measured, and the quality of each answer against the tight optimum: cost excess,
   constraint violation, first-input difference.
3. Closed loop: each back-end also drives its own closed loop on the same corridors; the
   controller's whole step (``Command.solve_ms``) and the tracking error are reported.
4. Construction: a fresh process builds the controller with an empty cache (code
   generation + compilation) and a second process with the filled cache.

5. With ``--mujoco SEEDS``: each back-end drives SA-MPC in MuJoCo on the five built-in
   scenarios x SEEDS random initial yaws (the harness of ``sanav-mj run``); outcomes and the
   wall (``solve_ms``) and CPU time of every controller step.

   With ``--footprint disc discs`` both footprint modes side by side (each with its own map
   and plan, episodes interleaved), and for each the solver call's share of the step; with
   ``--mujoco-only`` nothing else is run.

Usage: ``python scripts/bench_solvers.py [--solvers zerofpr panoc pantr ipopt] [--horizon 20] [--mujoco 10]``;
the issue-14 step target: ``python scripts/bench_solvers.py --solvers zerofpr --mujoco 5 --mujoco-only
--footprint disc discs``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import dataclasses

import numpy as np

from sanav_mj.control.base import Observation
from sanav_mj.control.backends import make_backend
from sanav_mj.control.problem import shift_bound_multipliers, shift_inputs, shift_multipliers
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig
from sanav_mj.control.unicycle import step_np
from sanav_mj.mapping.safe_areas import SafeAreas
from sanav_mj.planning.reference import Plan, Reference
from sanav_mj.scene import RobotParams

BUILTIN = ("single_rect", "double_rect", "u_shape", "v_shape", "complex")


def robot_params() -> RobotParams:
    """The robot of ``models/diff_drive.xml`` (read through a built-in scenario)."""
    from sanav_mj.scene import load_scenario

    return load_scenario("single_rect").robot


ROBOT = robot_params()

CORRIDORS = {
    # name: (rects, corridor, waypoints, start yaw)
    "L": (
        [[0.0, 0.0, 5.0, 1.2], [3.8, 1.2, 5.0, 4.0], [3.8, 4.0, 8.0, 5.0]],
        [0, 1, 2],
        [[0.5, 0.6], [4.4, 0.6], [4.4, 4.5], [7.5, 4.5]],
        1.0,
    ),
    "U": (
        [[0.0, 0.0, 1.0, 3.0], [0.0, 3.0, 4.0, 4.0], [3.0, 0.0, 4.0, 3.0]],
        [0, 1, 2],
        [[0.5, 0.5], [0.5, 3.5], [3.5, 3.5], [3.5, 0.5]],
        -2.0,
    ),
}


def make_case(name: str, speed: float = 0.8, dt: float = 0.1) -> tuple[SafeAreas, Plan]:
    """Safe areas and a plan whose reference runs along the waypoints at ``speed`` [m/s]."""
    rects, corridor, waypoints, _ = CORRIDORS[name]
    rects = np.asarray(rects, float)
    edges, portals = [], []
    for i, j in zip(corridor[:-1], corridor[1:]):
        lo = np.maximum(rects[i, :2], rects[j, :2])
        hi = np.minimum(rects[i, 2:], rects[j, 2:])
        edges.append((min(i, j), max(i, j)))
        portals.append([lo, hi])
    centres = (rects[:, :2] + rects[:, 2:]) / 2
    areas = SafeAreas(
        rects=rects,
        edges=np.array(edges),
        weights=np.array([np.hypot(*(centres[i] - centres[j])) for i, j in edges]),
        portals=np.array(portals),
    )
    wp = np.asarray(waypoints, float)
    cum = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(wp, axis=0).T))))
    s, v, acc, out = 0.0, 0.0, 0.8, [0.0]
    while s < cum[-1] - 1e-9:
        v = max(0.02, min(speed, v + acc * dt, np.sqrt(2 * acc * (cum[-1] - s))))
        s = min(cum[-1], s + v * dt)
        out.append(s)
    s_arr = np.array(out)
    xy = np.column_stack([np.interp(s_arr, cum, wp[:, i]) for i in range(2)])
    d = np.diff(xy, axis=0)
    yaw = np.unwrap(np.concatenate((np.arctan2(d[:, 1], d[:, 0]), [np.arctan2(d[-1, 1], d[-1, 0])])))
    inputs = np.column_stack((np.append(np.hypot(*d.T) / dt, 0.0), np.append(np.diff(yaw) / dt, 0.0)))
    area = np.array(
        [next(r for r in corridor if np.all(p >= rects[r, :2] - 1e-9) and np.all(p <= rects[r, 2:] + 1e-9)) for p in xy]
    )
    ref = Reference(dt=dt, states=np.column_stack((xy, yaw)), inputs=inputs, area=area)
    plan = Plan(True, "ok", np.array(corridor), wp[-1], wp, wp, xy, ref)
    return areas, plan


def builtin_cases() -> dict:
    """The built-in scenarios mapped and planned as the pipeline does: name -> (areas, plan, start yaw)."""
    from sanav_mj.eval.prepare import initial_pose, prepare
    from sanav_mj.scene import load_scenario

    out = {}
    for name in BUILTIN:
        scenario = load_scenario(name)
        start = initial_pose(scenario, 0, None)
        prep = prepare(scenario, start=start)
        if prep.plan.ok:
            out[name] = (prep.areas, prep.plan, float(start[2]))
    return out


def closed_loop(ctl: SAMPC, plan: Plan, yaw: float, steps: int = 400, record: list | None = None) -> dict:
    """Drive the controller with the mismatched kinematic plant; optionally record each OCP."""
    be = ctl.backend
    real = be.solve
    if record is not None:

        def recording(*args):
            res = real(*args)
            record.append((args[:5], res.z.copy()))
            return res

        be.solve = recording
    try:
        x = np.array([*plan.reference.states[0, :2], yaw])
        ctl.reset(x)
        ms, err, reached = [], [], False
        ref_xy = plan.smoothed
        vel = np.zeros(2)  # the body velocity the plant measures: the last applied input
        for k in range(steps):
            cmd = ctl.step(Observation(t=k * ctl.dt, pose=x.copy(), velocity=vel.copy()))
            ms.append(cmd.solve_ms)
            vel = np.array([0.95 * cmd.v, 1.05 * cmd.w])
            x = step_np(x, vel, ctl.dt)
            err.append(np.min(np.hypot(*(ref_xy - x[:2]).T)))
            if np.hypot(*(x[:2] - plan.goal)) < 0.05 and abs(cmd.v) < 0.05:
                reached = True
                break
    finally:
        be.solve = real
    ms = np.array(ms)
    return {
        "reached": reached,
        "steps": k + 1,
        "step_ms_mean": float(ms.mean()),
        "step_ms_p99": float(np.percentile(ms, 99)),
        "step_ms_max": float(ms.max()),
        "track_err_mean_m": float(np.mean(err)),
        "track_err_max_m": float(np.max(err)),
        "failures": ctl.stats.failures,
        "counts": dict(ctl.stats.counts),
        "step_ms": ms.tolist(),
    }


def replay(backends: dict, ocp, problems, rate_step) -> dict:
    """Solve the recorded problems in order with every back-end, each warm-started from its
    own shifted previous solution; the back-ends take turns problem by problem (starting
    with a different one each time), so that a change of the machine's load affects them
    alike and their time ratios stay meaningful. Returns name -> statistics."""
    import casadi as cs

    fcost = cs.Function("f", [ocp.z, ocp.p], [ocp.f])
    gfun = cs.Function("g", [ocp.z, ocp.p], [ocp.g])
    n = ocp.horizon
    names = list(backends)
    acc = {name: {"wall": [], "cpu": [], "excess": [], "viol": [], "du0": [], "iters": [], "conv": 0, "prev": None}
           for name in names}  # fmt: skip
    for i, ((p, z_lb, z_ub, g_lb, g_ub), z_star) in enumerate(problems):
        f_star = float(fcost(z_star, p))
        for j in range(len(names)):
            name = names[(i + j) % len(names)]
            a, prev = acc[name], acc[name]["prev"]
            if prev is None:
                z0, y0, yz0 = np.zeros(2 * n), None, None
            else:
                z0 = shift_inputs(prev.z.reshape(n, 2), 1, n, rate_step, prev.z[:2]).ravel()
                y0 = shift_multipliers(ocp, prev.y, shift_rates=False)  # as SAMPC does
                yz0 = shift_bound_multipliers(prev.y_z)
            z0 = np.clip(z0, z_lb, z_ub)
            t0, c0 = time.perf_counter(), time.process_time()
            res = backends[name].solve(p, z_lb, z_ub, g_lb, g_ub, z0, y0, yz0)
            a["wall"].append((time.perf_counter() - t0) * 1e3)
            a["cpu"].append((time.process_time() - c0) * 1e3)
            a["prev"] = res
            a["conv"] += res.converged
            a["iters"].append(res.iterations)
            a["excess"].append(float(fcost(res.z, p)) - f_star)
            g = np.array(gfun(res.z, p)).ravel()
            a["viol"].append(max(np.max(g_lb - g, initial=0), np.max(g - g_ub, initial=0),
                                 np.max(z_lb - res.z, initial=0), np.max(res.z - z_ub, initial=0)))  # fmt: skip
            a["du0"].append(float(np.max(np.abs(res.z[:2] - z_star[:2]))))
    out = {}
    for name in names:
        a = acc[name]
        wall, cpu = np.array(a["wall"]), np.array(a["cpu"])
        out[name] = {
            "solves": len(wall),
            "converged": int(a["conv"]),
            "wall_ms_mean": float(wall.mean()),
            "wall_ms_p50": float(np.median(wall)),
            "wall_ms_p99": float(np.percentile(wall, 99)),
            "wall_ms_max": float(wall.max()),
            "cpu_ms_mean": float(cpu.mean()),
            "cpu_ms_p99": float(np.percentile(cpu, 99)),
            "iterations_mean": float(np.mean(a["iters"])),
            "cost_excess_mean": float(np.mean(a["excess"])),
            "cost_excess_max": float(np.max(a["excess"])),
            "violation_max": float(np.max(a["viol"])),
            "du0_max": float(np.max(a["du0"])),
        }
    return out


def replay_min(make, pose0: np.ndarray, observations: list, commands: list, repeats: int) -> np.ndarray:
    """Per-step minimum wall time [ms] (S,) of ``repeats`` replays of an episode's
    ``observations`` (S,) through fresh controllers ``make()`` reset at ``pose0`` (3,).

    The controller is deterministic given its observations, so every replay poses and solves
    the very problems of the episode (checked: each replayed command equals the episode's
    ``commands``, else RuntimeError); the minimum over the replays drops the time a step
    spent waiting for a core on a loaded machine, which a single run cannot separate."""
    best = np.full(len(observations), np.inf)
    for _ in range(repeats):
        ctl = make()
        ctl.reset(pose0)
        for i, obs in enumerate(observations):
            t0 = time.perf_counter()
            cmd = ctl.step(obs)
            best[i] = min(best[i], (time.perf_counter() - t0) * 1e3)
            if (cmd.v, cmd.w) != (commands[i].v, commands[i].w):
                raise RuntimeError(f"replay step {i}: command {(cmd.v, cmd.w)} differs from the episode's "
                                   f"{(commands[i].v, commands[i].w)}")
    return best


def mujoco_loops(solvers: list[str], seeds: int, footprints: tuple[str, ...] = ("disc",), replays: int = 0) -> dict:
    """The five built-in scenarios x ``seeds`` random initial yaws in MuJoCo (``sanav-mj run``'s
    harness) with SA-MPC on each of ``solvers`` and each of ``footprints`` (``MPCConfig.footprint``:
    ``"disc"`` and / or ``"discs"``, each with its own map and plan, as ``run --footprint``),
    taking turns episode by episode so a change of the machine's load hits them alike:
    outcomes, the per-step wall time (``solve_ms``) and CPU time of ``SAMPC.step``, and the
    part of the wall time spent in the solver back-end's call (``SolveResult.solver_ms``; the
    rest is the Python around it). With ``replays`` > 0 also the per-step minimum over that
    many replays of each episode (:func:`replay_min`). Returns ``solver`` -> statistics for
    the disc footprint alone, else ``"solver:footprint"`` -> statistics."""
    from sanav_mj.control.factory import make_controller
    from sanav_mj.control.spec import ControllerSpec
    from sanav_mj.eval.episode import run_scenario
    from sanav_mj.eval.prepare import initial_pose, prepare
    from sanav_mj.scene import load_scenario

    keys = [(s, f) for s in solvers for f in footprints]
    acc = {k: {"runs": [], "wall": [], "cpu": [], "solver": [], "turn": [], "statuses": {}, "replay": []} for k in keys}
    for name in BUILTIN:
        scenario = load_scenario(name)
        for seed in range(seeds):
            start = initial_pose(scenario, seed, None)
            for fp in footprints:
                spec = ControllerSpec("sa-mpc", dataclasses.replace(MPCConfig(solve_budget_ms=None), footprint=fp))
                prep = prepare(scenario, start=start, controller=spec)
                for solver in solvers:
                    a = acc[(solver, fp)]
                    spec_s = ControllerSpec("sa-mpc", dataclasses.replace(spec.sa_mpc, solver=solver))
                    ctl = make_controller(spec_s, prep.scenario, prep.grid, prep.areas, prep.plan)
                    step, solve = ctl.step, ctl.solve
                    cell = [0.0]
                    log: tuple[list, list] = ([], [])

                    def timed(obs, step=step, cpu=a["cpu"], sol=a["solver"], cell=cell, log=log):
                        if replays:
                            log[0].append(copy.deepcopy(obs))
                        cell[0] = 0.0
                        c0 = time.process_time()
                        cmd = step(obs)
                        cpu.append((time.process_time() - c0) * 1e3)
                        sol.append(cell[0])
                        log[1].append(cmd)
                        return cmd

                    def solve_timed(prob, x0, solve=solve, cell=cell):
                        out = solve(prob, x0)
                        cell[0] += out[0].solver_ms
                        return out

                    ctl.step, ctl.solve = timed, solve_timed
                    ep = run_scenario(prep, "sa-mpc", seed=seed, controller_obj=ctl, controller_spec=spec_s).episode
                    a["wall"].extend(ep.trace.solve_ms)
                    if replays:
                        def make(spec_s=spec_s, prep=prep):
                            return make_controller(spec_s, prep.scenario, prep.grid, prep.areas, prep.plan)

                        a["replay"].extend(replay_min(make, start, log[0], log[1], replays).tolist())
                    a["turn"].extend(st == "turn" for st in ep.trace.status)
                    for st in ep.trace.status:
                        a["statuses"][st] = a["statuses"].get(st, 0) + 1
                    a["runs"].append(
                        {"scenario": name, "seed": seed, "footprint": fp, "success": bool(ep.success),
                         "reason": ep.reason, "collisions": int(ep.collisions),
                         "fallback_steps": int(ep.solver_failures), "steps": int(ep.steps)}
                    )  # fmt: skip
    out = {}
    for solver, fp in keys:
        a = acc[(solver, fp)]
        runs = a["runs"]
        wall, cpu, mpc = np.array(a["wall"]), np.array(a["cpu"]), ~np.array(a["turn"], dtype=bool)
        sol = np.array(a["solver"])
        key = solver if footprints == ("disc",) else f"{solver}:{fp}"
        out[key] = {
            "footprint": fp,
            "runs": runs,
            "successes": sum(r["success"] for r in runs),
            "collisions": sum(r["collisions"] for r in runs),
            "fallback_steps": sum(r["fallback_steps"] for r in runs),
            "statuses": a["statuses"],
            "steps": int(wall.size),
            "wall_ms_mean": float(wall.mean()),
            "wall_ms_p50": float(np.median(wall)),
            "wall_ms_p99": float(np.percentile(wall, 99)),
            "wall_ms_max": float(wall.max()),
            "wall_over_5ms": float(np.mean(wall > 5.0)),
            "cpu_ms_mean": float(cpu.mean()),
            "cpu_ms_p99": float(np.percentile(cpu, 99)),
            "cpu_ms_max": float(cpu.max()),
            # the back-end's call (alpaqa / IPOPT itself) and the Python of the step around it
            "solver_ms_mean": float(sol.mean()),
            "python_ms_mean": float((wall - sol).mean()),
            "python_ms_p99": float(np.percentile(wall - sol, 99)),
            # the same without the opening turn's steps (no solve): the MPC steps alone
            "mpc_steps": int(mpc.sum()),
            "mpc_wall_ms_mean": float(wall[mpc].mean()),
            "mpc_wall_ms_p99": float(np.percentile(wall[mpc], 99)),
            "mpc_cpu_ms_mean": float(cpu[mpc].mean()),
            "mpc_cpu_ms_p99": float(np.percentile(cpu[mpc], 99)),
            "load_avg_1min": os.getloadavg()[0],
        }
        if replays:
            rep = np.array(a["replay"])
            out[key].update({"replays": replays, "replay_min_ms_mean": float(rep.mean()),
                             "replay_min_ms_p50": float(np.median(rep)), "replay_min_ms_p99": float(np.percentile(rep, 99)),
                             "replay_min_ms_max": float(rep.max())})
    return out


_BUILD_SNIPPET = """
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, {scripts!r})
from bench_solvers import make_case, ROBOT
from sanav_mj.control.sa_mpc import SAMPC, MPCConfig
areas, plan = make_case("L")
t1 = time.perf_counter()
ctl = SAMPC(ROBOT, areas, plan, MPCConfig(solver={solver!r}, horizon={horizon}, solve_budget_ms=None))
t2 = time.perf_counter()
print(json.dumps({{"imports_s": t1 - t0, "build_s": t2 - t1, "compiled": bool(getattr(ctl.backend, "compiled", False))}}))
"""


def build_times(solver: str, horizon: int) -> dict:
    """Controller construction time in a fresh process with an empty, then a filled, cache."""
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, SANAV_MJ_CACHE=cache)
        code = _BUILD_SNIPPET.format(scripts=str(Path(__file__).resolve().parent), solver=solver, horizon=horizon)
        for label in ("first_process", "second_process"):
            proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out[label] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def print_mujoco(loops: dict, seeds: int) -> None:
    """Print :func:`mujoco_loops`' statistics, one block per solver (and footprint)."""
    print(f"\nMuJoCo: five built-in scenarios x {seeds} random initial yaws (SAMPC.step per control step)")
    ipopt = loops.get("ipopt")
    for key, m in loops.items():
        ratio = ipopt["wall_ms_mean"] / m["wall_ms_mean"] if ipopt else float("nan")
        print(f"{key:14s} success {m['successes']}/{len(m['runs'])} collisions {m['collisions']} fallback steps "
              f"{m['fallback_steps']} | wall mean {m['wall_ms_mean']:.2f} p50 {m['wall_ms_p50']:.2f} p99 "
              f"{m['wall_ms_p99']:.2f} max {m['wall_ms_max']:.1f} ms ({m['wall_over_5ms'] * 100:.1f} % > 5 ms) | cpu mean "
              f"{m['cpu_ms_mean']:.2f} p99 {m['cpu_ms_p99']:.2f} max {m['cpu_ms_max']:.1f} ms | IPOPT/this {ratio:.1f}x "
              f"| {m['steps']} steps, load {m['load_avg_1min']:.1f}")  # fmt: skip
        print(f"{'':14s} MPC steps only ({m['mpc_steps']}, without the opening turn): wall mean "
              f"{m['mpc_wall_ms_mean']:.2f} p99 {m['mpc_wall_ms_p99']:.2f} | cpu mean {m['mpc_cpu_ms_mean']:.2f} "
              f"p99 {m['mpc_cpu_ms_p99']:.2f} ms")  # fmt: skip
        print(f"{'':14s} of the wall mean: solver call {m['solver_ms_mean']:.2f} ms, Python around it "
              f"{m['python_ms_mean']:.2f} ms (p99 {m['python_ms_p99']:.2f})")
        if "replays" in m:
            print(f"{'':14s} per-step minimum of {m['replays']} replays: mean {m['replay_min_ms_mean']:.2f} p50 "
                  f"{m['replay_min_ms_p50']:.2f} p99 {m['replay_min_ms_p99']:.2f} max {m['replay_min_ms_max']:.1f} ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--solvers", nargs="+", default=["zerofpr", "panoc", "pantr", "ipopt"])
    ap.add_argument("--horizon", type=int, default=20)
    ap.add_argument("--no-build", action="store_true", help="skip the construction-time measurement")
    ap.add_argument("--no-scenarios", action="store_true", help="only the synthetic L and U corridors")
    ap.add_argument("--mujoco", type=int, default=0, metavar="SEEDS",
                    help="also run the five built-in scenarios x SEEDS random yaws in MuJoCo per back-end")
    ap.add_argument("--footprint", nargs="+", choices=("disc", "discs"), default=["disc"],
                    help="--mujoco: SA-MPC's footprint mode(s) (MPCConfig.footprint), run side by side")
    ap.add_argument("--replays", type=int, default=0, metavar="K",
                    help="--mujoco: also replay each episode K times and report the per-step minimum")
    ap.add_argument("--mujoco-only", action="store_true",
                    help="only the MuJoCo loops (--mujoco): no recording, replay, closed loops or build")
    ap.add_argument("--json", type=Path, help="write all results to this file")
    args = ap.parse_args(argv)
    if args.mujoco_only and not args.mujoco:
        ap.error("--mujoco-only needs --mujoco SEEDS")
    if args.mujoco_only:
        results = {"load_avg_start": os.getloadavg(), "mujoco": mujoco_loops(args.solvers, args.mujoco,
                                                                              tuple(args.footprint), args.replays)}
        results["load_avg_end"] = os.getloadavg()
        print_mujoco(results["mujoco"], args.mujoco)
        print(f"\nload average (1, 5, 15 min): start {results['load_avg_start']}, end {results['load_avg_end']}")
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))
        return 0

    # No wall-clock budget anywhere: every back-end runs to its own convergence (under load a
    # budget would cut IPOPT's slow solves short and spoil the reference).
    base = MPCConfig(horizon=args.horizon, solve_budget_ms=None)
    # 1. record the sequence with a tight IPOPT
    problems = []
    cases = {name: (*make_case(name), CORRIDORS[name][3]) for name in CORRIDORS}
    if not args.no_scenarios:
        cases.update(builtin_cases())
    for name, (areas, plan, yaw) in cases.items():
        ctl = SAMPC(ROBOT, areas, plan, dataclasses.replace(base, solver="ipopt", tol=1e-9, constraint_tol=1e-9))
        n0 = len(problems)
        closed_loop(ctl, plan, yaw, record=problems)
        print(f"recorded {len(problems) - n0} problems on {name}")
    ocp = ctl.ocp
    rate_step = ctl.limits.rate() * ctl.dt
    print(f"recorded {len(problems)} problems in all (N = {args.horizon})")

    results: dict = {
        "horizon": args.horizon, "problems": len(problems), "replay": {}, "closed_loop": {}, "build": {}, "mujoco": {},
        "load_avg_start": os.getloadavg(),
    }  # fmt: skip
    backends = {s: make_backend(s, ocp, dataclasses.replace(base, solver=s).solver_settings()) for s in args.solvers}
    replay(backends, ocp, problems[:20], rate_step)  # warm-up (page-in, first calls)
    results["replay"] = replay(backends, ocp, problems, rate_step)
    for solver in args.solvers:
        results["closed_loop"][solver] = {}
    for name, (areas, plan, yaw) in cases.items():
        for solver in args.solvers:
            ctl = SAMPC(ROBOT, areas, plan, dataclasses.replace(base, solver=solver))
            results["closed_loop"][solver][name] = closed_loop(ctl, plan, yaw)
    for solver in args.solvers:
        if not args.no_build:
            results["build"][solver] = build_times(solver, args.horizon)
    if args.mujoco:
        results["mujoco"] = mujoco_loops(args.solvers, args.mujoco, tuple(args.footprint), args.replays)
    results["load_avg_end"] = os.getloadavg()

    ref = results["replay"].get("ipopt")
    print("\nReplay of the recorded sequence (per solve, Python call included; back-ends interleaved)")
    print(f"{'solver':8s} {'wall mean':>9s} {'p50':>6s} {'p99':>6s} {'max':>6s} {'cpu mean':>8s} {'x IPOPT':>7s} "
          f"{'(cpu)':>6s} {'iters':>6s} {'conv':>5s} {'cost excess mean/max':>22s} {'viol max':>9s} {'|du0| max':>9s}")  # fmt: skip
    for solver, r in results["replay"].items():
        ratio = ref["wall_ms_mean"] / r["wall_ms_mean"] if ref else float("nan")
        ratio_cpu = ref["cpu_ms_mean"] / r["cpu_ms_mean"] if ref else float("nan")
        r["ipopt_ratio_wall"], r["ipopt_ratio_cpu"] = ratio, ratio_cpu
        print(
            f"{solver:8s} {r['wall_ms_mean']:9.3f} {r['wall_ms_p50']:6.3f} {r['wall_ms_p99']:6.2f} {r['wall_ms_max']:6.2f} "
            f"{r['cpu_ms_mean']:8.3f} {ratio:7.1f} {ratio_cpu:6.1f} {r['iterations_mean']:6.1f} {r['converged']:5d} "
            f"{r['cost_excess_mean']:10.2e}/{r['cost_excess_max']:9.2e} {r['violation_max']:9.1e} {r['du0_max']:9.1e}"
        )
    print("\nClosed loops (controller step incl. Python, tracking error to the reference path)")
    for solver, loops in results["closed_loop"].items():
        ms = np.concatenate([r["step_ms"] for r in loops.values()])
        print(f"{solver:8s} all: step ms mean {ms.mean():.3f} p50 {np.median(ms):.3f} p99 {np.percentile(ms, 99):.2f} "
              f"max {ms.max():.2f} over {len(ms)} steps")  # fmt: skip
        for name, r in loops.items():
            print(
                f"{solver:8s} {name}: reached={r['reached']} steps={r['steps']} step ms mean {r['step_ms_mean']:.3f} "
                f"p99 {r['step_ms_p99']:.2f} max {r['step_ms_max']:.2f}; track err mean {r['track_err_mean_m'] * 100:.2f} cm "
                f"max {r['track_err_max_m'] * 100:.2f} cm; failures {r['failures']}"
            )
    if results["build"]:
        print("\nController construction (fresh process; empty cache, then filled cache)")
        for solver, b in results["build"].items():
            f, s = b["first_process"], b["second_process"]
            print(f"{solver:8s} first {f['build_s']:.2f} s (compiled={f['compiled']}), second {s['build_s']:.3f} s "
                  f"(compiled={s['compiled']}); imports {s['imports_s']:.2f} s")  # fmt: skip
    if results["mujoco"]:
        print_mujoco(results["mujoco"], args.mujoco)
    print(f"\nload average (1, 5, 15 min): start {results['load_avg_start']}, end {results['load_avg_end']}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
