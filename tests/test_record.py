"""Tests of sanav_mj.record: the recording is read back with rerun's own reader and CLI."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from _helpers import make_prep

from sanav_mj.mapping.quadtree import QuadtreeLeaves
from sanav_mj.record import RecordConfig, Recorder, leaf_rects, robot_footprint
from sanav_mj.resources import robot_model_path
from sanav_mj.sim.runner import Episode, EpisodeTrace

N_STEPS = 30
HORIZON = 5


# ---------------------------------------------------------------------------- fixtures
def make_trace(n: int = N_STEPS, horizon: int = HORIZON) -> EpisodeTrace:
    """A synthetic trace: horizon missing every 7th step (k % 7 == 3), a fallback every 10th
    step, a negative margin at step 5, a contact at the last step."""
    tr = EpisodeTrace()
    for k in range(n):
        pose = np.array([4.0 * k / n, -0.8 * np.sin(np.pi * k / n), 0.1 * k])
        tr.t.append(0.1 * k)
        tr.pose.append(pose)
        tr.measured.append(pose + 0.01)
        tr.cmd.append((0.5 + 0.01 * k, 0.1))
        tr.applied.append((0.5 + 0.01 * (k - 1), 0.1))
        tr.velocity.append(np.array([0.45, 0.09 + 0.001 * k]))
        tr.wheel_cmd.append(np.array([4.8, 5.2]))
        tr.wheel_speed.append(np.array([4.5, 5.0 - 0.01 * k]))
        tr.solve_ms.append(2.0 + k % 3)
        tr.pipeline_ms.append(2.5 + k % 3)
        tr.status.append("ok" if k % 10 else "fallback_shift")
        tr.ok.append(k % 10 != 0)
        tr.clearance.append(0.5 - 0.01 * k)
        tr.contacts.append(1 if k == n - 1 else 0)
        if k % 7 == 3:
            tr.predicted.append(None)
            tr.rect_ids.append(None)
            tr.margins.append(None)
        else:
            tr.predicted.append(pose + np.outer(0.05 * np.arange(horizon + 1), [1.0, 0.0, 0.0]))
            tr.rect_ids.append(np.array([1] * (horizon // 2) + [0] * (horizon + 1 - horizon // 2)))
            tr.margins.append(np.linspace(0.3, -0.1 if k == 5 else 0.1, horizon + 1))
    return tr


def replay(rec: Recorder, full: EpisodeTrace) -> EpisodeTrace:
    """Feed ``full`` to ``rec.log_step`` one step at a time as the runner does (growing trace)."""
    part = EpisodeTrace()
    for k in range(len(full)):
        for f in dataclasses.fields(EpisodeTrace):
            getattr(part, f.name).append(getattr(full, f.name)[k])
        rec.log_step(k, part)
    return part


def episode_of(tr: EpisodeTrace) -> Episode:
    n = len(tr)
    return Episode(False, "collision", n, 0.1 * n, 1, 3, np.array([4.0, 0.0, 3.0]), tr, 0.5)


DOC = {"scenario": "fixture", "controller": "sa-mpc", "seed": 0, "success": False, "reason": "collision",
       "steps": N_STEPS, "solve_ms": {"mean": 3.0, "p99": 4.0}, "trace": {"t": [0.0]}}


def read_rrd(path: Path) -> dict[str, dict]:
    """Per entity: static rows, temporal rows, timelines, step values and component values
    (one list entry per row), read with rerun's own chunk reader."""
    out: dict[str, dict] = {}
    for chunk in RrdReader(path).stream():
        e = out.setdefault(chunk.entity_path, {"static": 0, "rows": 0, "timelines": set(), "steps": [], "data": {}})
        rb = chunk.to_record_batch()
        if chunk.is_static:
            e["static"] += chunk.num_rows
        else:
            e["rows"] += chunk.num_rows
            e["timelines"].update(chunk.timeline_names)
            e["steps"].extend(rb.column("step").to_pylist())
        for name in rb.schema.names:
            if ":" in name:
                e["data"].setdefault(name, []).extend(rb.column(name).to_pylist())
    return out


def scalars_by_step(e: dict) -> np.ndarray:
    vals = [row[0] for row in e["data"]["Scalars:scalars"]]
    order = np.argsort(e["steps"])
    return np.asarray(vals)[order]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, EpisodeTrace]:
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    full = make_trace()
    rec = Recorder(path, make_prep(), "sa-mpc", RecordConfig(flush_every=7))
    part = replay(rec, full)
    rec.finish(episode_of(part), DOC)
    return path, full


# ---------------------------------------------------------------------------- read back
STATIC = [
    "/world", "/world/workspace", "/world/obstacles/boxes", "/world/obstacles/round", "/world/grid",
    "/world/quadtree/free", "/world/quadtree/occupied", "/world/safe_areas", "/world/graph/edges",
    "/world/graph/nodes", "/world/plan/corridor", "/world/plan/waypoints", "/world/plan/path",
    "/world/plan/reference", "/world/plan/reference/samples", "/world/start", "/world/goal",
    "/world/robot/footprint", "/world/robot/heading", "/summary",
]
PER_STEP = [
    "/world/measured", "/plots/velocity/v_cmd", "/plots/velocity/v_meas", "/plots/velocity/w_cmd",
    "/plots/velocity/w_meas", "/plots/wheels/left_cmd", "/plots/wheels/left_meas", "/plots/wheels/right_cmd",
    "/plots/wheels/right_meas", "/plots/slip/v", "/plots/slip/w", "/plots/timing/solve_ms",
    "/plots/timing/pipeline_ms", "/plots/safety/clearance", "/plots/safety/contacts", "/plots/solver/ok",
]


def test_static_entities_logged_once(recorded):
    path, _ = recorded
    ents = read_rrd(path)
    for name in STATIC:
        assert name in ents, name
        assert ents[name]["static"] >= 1 and ents[name]["rows"] == 0, name
    # Instance counts of the static map layers.
    assert len(ents["/world/safe_areas"]["data"]["Boxes2D:centers"][0]) == 3
    assert len(ents["/world/graph/edges"]["data"]["LineStrips2D:strips"][0]) == 2
    assert len(ents["/world/quadtree/free"]["data"]["Boxes2D:centers"][0]) == 4
    assert len(ents["/world/quadtree/occupied"]["data"]["Boxes2D:centers"][0]) == 2
    assert len(ents["/world/plan/corridor"]["data"]["Boxes2D:centers"][0]) == 3
    assert len(ents["/world/plan/reference/samples"]["data"]["Points2D:positions"][0]) == 21
    # Display-only y flip at the root of the 2D scene.
    assert ents["/world"]["data"]["Transform3D:scale"][0][0] == [1.0, -1.0, 1.0]
    # Grid placed at the world origin with the cell size as scale.
    tf = ents["/world/grid"]["data"]
    assert tf["Transform3D:translation"][0][0] == pytest.approx([-1.0, -2.0, 0.0])
    assert tf["Transform3D:scale"][0][0] == pytest.approx([0.5, 0.5, 1.0])


def test_per_step_counts_and_timelines(recorded):
    path, full = recorded
    ents = read_rrd(path)
    n = len(full)
    for name in PER_STEP:
        e = ents[name]
        assert e["rows"] == n, name
        assert sorted(e["steps"]) == list(range(n)), name
        assert e["timelines"] == {"step", "sim_time"}, name
    # Robot pose and trail: every step plus the final pose at step n.
    for name in ("/world/robot", "/world/trail"):
        assert sorted(ents[name]["steps"]) == list(range(n + 1)), name
    has_h = [k for k in range(n) if full.predicted[k] is not None]
    assert sorted(ents["/world/horizon/predicted"]["steps"]) == has_h
    assert sorted(ents["/world/horizon/rects"]["steps"]) == has_h
    assert sorted(ents["/plots/safety/margin_min"]["steps"]) == has_h
    pts = ents["/world/horizon/points"]["data"]["Points2D:positions"]
    assert [len(r) for r in pts] == [HORIZON + 1] * len(has_h)
    # Two distinct areas (1 and 0) assigned to every horizon.
    assert all(len(r) == 2 for r in ents["/world/horizon/rects"]["data"]["Boxes2D:centers"])
    assert ents["/world/collisions"]["steps"] == [n - 1]
    # Status log: the first step and every change (fallback at 0, 10, 20; ok after them).
    assert sorted(ents["/solver/status"]["steps"]) == [0, 1, 10, 11, 20, 21]


def test_values_round_trip(recorded):
    path, full = recorded
    ents = read_rrd(path)
    cmd = np.asarray(full.cmd)
    applied = np.asarray(full.applied)
    vel = np.asarray(full.velocity)
    np.testing.assert_array_equal(scalars_by_step(ents["/plots/velocity/v_cmd"]), cmd[:, 0])
    np.testing.assert_array_equal(scalars_by_step(ents["/plots/wheels/right_meas"]), np.asarray(full.wheel_speed)[:, 1])
    np.testing.assert_allclose(scalars_by_step(ents["/plots/slip/w"]), applied[:, 1] - vel[:, 1], atol=1e-15)
    margins = [float(np.min(m)) for m in full.margins if m is not None]
    np.testing.assert_allclose(scalars_by_step(ents["/plots/safety/margin_min"]), margins)
    # Robot transform: translation = true pose, quaternion encodes the yaw.
    e = ents["/world/robot"]
    order = np.argsort(e["steps"])
    trans = np.array([r[0] for r in e["data"]["Transform3D:translation"]])[order]
    quat = np.array([r[0] for r in e["data"]["Transform3D:quaternion"]])[order]
    poses = np.vstack((full.poses(), [[4.0, 0.0, 3.0]]))
    # float32 in the file: rounding to nearest is within half a float32 ulp of the largest coordinate
    np.testing.assert_allclose(trans[:, :2], poses[:, :2], rtol=0, atol=0.5 * float(np.spacing(np.float32(np.abs(poses[:, :2]).max()))))
    # float32 quaternion components (each within 2^-25 of a unit-norm value): the half-angle
    # atan2 moves by <= (|cos| + |sin|) 2^-25 <= sqrt(2) 2^-25, the yaw by twice that (8.4e-8)
    np.testing.assert_allclose(2 * np.arctan2(quat[:, 2], quat[:, 3]), poses[:, 2], rtol=0, atol=2 * np.sqrt(2) * 2.0**-25 + 4 * np.finfo(float).eps)
    # Negative margin at step 5 colours that horizon's last point red.
    hp = ents["/world/horizon/points"]
    row = hp["steps"].index(5)
    colors = hp["data"]["Points2D:colors"][row]
    assert colors[-1] != colors[0]
    # Summary: markdown with the JSON document, without the trace.
    text = ents["/summary"]["data"]["TextDocument:text"][0][0]
    body = text.split("```json\n", 1)[1].split("\n```", 1)[0]
    doc = json.loads(body)
    assert doc["reason"] == "collision" and "trace" not in doc


def test_blueprint_sent_with_the_recording(recorded):
    path, _ = recorded
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1
    (bp,) = reader.blueprints()
    classes, origins = set(), set()
    for chunk in reader.stream(store=bp):
        rb = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in rb.schema.names:
            classes.update(v[0] for v in rb.column("ViewBlueprint:class_identifier").to_pylist())
            origins.update(v[0] for v in rb.column("ViewBlueprint:space_origin").to_pylist())
    assert {"2D", "TimeSeries", "TextLog", "TextDocument"} <= classes
    assert {"/plots/velocity", "/plots/wheels", "/plots/slip", "/plots/timing", "/plots/safety"} <= origins


def rrd_verify(path: Path) -> subprocess.CompletedProcess:
    """``rerun rrd verify PATH`` (the CLI installed with rerun-sdk)."""
    exe = shutil.which("rerun")
    if exe is None:
        pytest.fail("the rerun CLI (installed with rerun-sdk) is not on PATH")
    return subprocess.run([exe, "rrd", "verify", str(path)], check=False, capture_output=True, text=True, timeout=120)


def test_rrd_verify_passes(recorded):
    path, _ = recorded
    res = rrd_verify(path)
    assert res.returncode == 0, res.stderr
    assert "verified without error" in (res.stdout + res.stderr)


def test_rrd_verify_fails_on_a_truncated_file(recorded, tmp_path):
    path, _ = recorded
    bad = tmp_path / "cut.rrd"
    bad.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    res = rrd_verify(bad)
    assert res.returncode != 0


# ---------------------------------------------------------------------------- behaviour
def test_batched_equals_step_by_step(tmp_path):
    full = make_trace()
    got = {}
    for every in (1, 50):
        path = tmp_path / f"every{every}.rrd"
        rec = Recorder(path, make_prep(), "sa-mpc", RecordConfig(flush_every=every))
        rec.finish(episode_of(replay(rec, full)), DOC)
        got[every] = read_rrd(path)
    assert got[1].keys() == got[50].keys()
    for name in [n for n in PER_STEP if n.startswith("/plots/")] + ["/plots/safety/margin_min"]:
        np.testing.assert_array_equal(scalars_by_step(got[1][name]), scalars_by_step(got[50][name]))
    for name in ("/world/robot", "/world/measured", "/world/horizon/predicted", "/world/horizon/rects",
                 "/solver/status"):
        assert sorted(got[1][name]["steps"]) == sorted(got[50][name]["steps"]), name


def test_no_global_recording_is_created(tmp_path):
    rec = Recorder(tmp_path / "a.rrd", make_prep(), "sa-mpc")
    assert rr.get_global_data_recording() is None
    rec.finish(episode_of(EpisodeTrace()), DOC)
    assert rr.get_global_data_recording() is None


def test_empty_episode_records_map_and_summary(tmp_path):
    """A run that never stepped (no_path) still yields a valid file with the map and summary."""
    path = tmp_path / "empty.rrd"
    Recorder(path, make_prep(), "sa-mpc").finish(episode_of(EpisodeTrace()), {**DOC, "reason": "no_path"})
    ents = read_rrd(path)
    assert "/world/safe_areas" in ents and "/summary" in ents
    assert "/world/robot" not in ents
    res = rrd_verify(path)
    assert res.returncode == 0, res.stderr


def test_misuse_is_a_clear_error(tmp_path):
    rec = Recorder(tmp_path / "m.rrd", make_prep(), "sa-mpc")
    tr = make_trace(3)
    with pytest.raises(ValueError, match="last index 2, got 1"):
        rec.log_step(1, tr)
    rec.finish(episode_of(tr), DOC)
    with pytest.raises(ValueError, match="already finished"):
        rec.finish(episode_of(tr), DOC)
    with pytest.raises(ValueError, match="already finished"):
        rec.log_step(2, tr)
    with pytest.raises(ValueError, match="flush_every"):
        RecordConfig(flush_every=0)
    with pytest.raises(ValueError, match=r"Prepared with \.scenario"):
        Recorder(tmp_path / "x.rrd", object(), "sa-mpc")


def test_context_manager_closes_a_valid_file(tmp_path):
    path = tmp_path / "ctx.rrd"
    full = make_trace(12)
    with pytest.raises(RuntimeError), Recorder(path, make_prep(), "sa-mpc", RecordConfig(flush_every=5)) as rec:
        replay(rec, full)
        raise RuntimeError("controller crashed")
    ents = read_rrd(path)
    assert ents["/plots/velocity/v_cmd"]["rows"] == 10  # two full batches were sent before the crash
    res = rrd_verify(path)
    assert res.returncode == 0, res.stderr


def test_ctrl_c_leaves_no_file(tmp_path):
    path = tmp_path / "sub" / "ctl.rrd"
    with pytest.raises(KeyboardInterrupt), Recorder(path, make_prep(), "sa-mpc", RecordConfig(flush_every=5)) as rec:
        replay(rec, make_trace(12))
        raise KeyboardInterrupt
    assert not path.parent.exists() or list(path.parent.iterdir()) == []  # no partial file, no .part file


def test_a_full_disk_is_an_error_naming_the_file_and_leaves_no_file(tmp_path, monkeypatch):
    """The SDK's own file sink only logged the write error (a cut file, exit 0): the bytes are
    written by sanav_mj.outputs, whose write error reaches the caller."""
    import errno

    from sanav_mj import outputs

    class FullFile:
        def __init__(self, path, mode):
            self.fh = open(path, mode)  # noqa: SIM115

        def write(self, data):
            self.fh.write(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    monkeypatch.setattr(outputs, "open", FullFile, raising=False)
    path = tmp_path / "full.rrd"
    rec = Recorder(path, make_prep(), "sa-mpc")
    with pytest.raises(OSError) as err:
        rec.finish(episode_of(replay(rec, make_trace())), DOC)
    assert (err.value.errno, err.value.filename) == (errno.ENOSPC, str(path))
    assert "No space left on device" in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_record_episode_equals_streaming(tmp_path):
    from sanav_mj.record import record_episode

    full = make_trace()
    streamed = tmp_path / "streamed.rrd"
    rec = Recorder(streamed, make_prep(), "sa-mpc", RecordConfig(flush_every=1))
    rec.finish(episode_of(replay(rec, full)), DOC)
    outcome = type("Outcome", (), {"prepared": make_prep(), "controller": "sa-mpc", "episode": episode_of(full),
                                   "document": DOC})()
    after = record_episode(tmp_path / "after.rrd", outcome)
    a, b = read_rrd(streamed), read_rrd(after)
    assert a.keys() == b.keys()
    for name in a:
        assert sorted(a[name]["steps"]) == sorted(b[name]["steps"]), name
    np.testing.assert_array_equal(scalars_by_step(a["/plots/velocity/v_cmd"]), scalars_by_step(b["/plots/velocity/v_cmd"]))
    assert rrd_verify(after).returncode == 0


# ---------------------------------------------------------------------------- geometry helpers
def test_robot_footprint_of_the_packaged_robot():
    """Deck 0.50 x 0.43 m; the wheels (0.19 + 0.025 m) reach the deck's side exactly."""
    model = mujoco.MjModel.from_xml_path(str(robot_model_path()))
    fp = robot_footprint(model)
    np.testing.assert_allclose(fp, [[0.25, 0.215], [-0.25, 0.215], [-0.25, -0.215], [0.25, -0.215]], atol=1e-9)


def test_leaf_rects_exact():
    leaves = QuadtreeLeaves(np.array([[0, 0, 2, 4], [2, 4, 3, 5]]), np.array([True, False]), np.zeros(2, dtype=np.int64))
    r = leaf_rects(leaves, np.array([1.0, -1.0]), 0.25)
    np.testing.assert_array_equal(r, [[1.0, -1.0, 2.0, -0.5], [2.0, -0.5, 2.25, -0.25]])


# ---------------------------------------------------------------------------- end to end
def test_cli_run_writes_a_recording_of_every_step(tmp_path):
    """``sanav-mj run u_shape --rrd F --json J``: the recording holds one row per control step
    of the run the JSON describes, the real map layers, and passes ``rerun rrd verify``."""
    from sanav_mj.cli import main

    rrd, js = tmp_path / "u.rrd", tmp_path / "u.json"
    code = main(["run", "u_shape", "--seed", "1", "--time-limit", "4", "--rrd", str(rrd), "--json", str(js)])
    doc = json.loads(js.read_text())
    assert code == (0 if doc["success"] else 1)
    steps = doc["steps"]
    assert steps > 10
    ents = read_rrd(rrd)
    for name in PER_STEP:
        assert sorted(ents[name]["steps"]) == list(range(steps)), name
    assert sorted(ents["/world/robot"]["steps"]) == list(range(steps + 1))
    assert ents["/world/horizon/predicted"]["rows"] > 0  # SA-MPC reports its prediction
    assert len(ents["/world/safe_areas"]["data"]["Boxes2D:centers"][0]) > 1
    np.testing.assert_allclose(scalars_by_step(ents["/plots/velocity/v_cmd"]), doc["trace"]["v"], atol=1e-12)
    e = ents["/world/robot"]
    trans = np.array([r[0] for r in e["data"]["Transform3D:translation"]])[np.argsort(e["steps"])]
    # float32 in the file: within half a float32 ulp of the largest |x|
    np.testing.assert_allclose(trans[:steps, 0], doc["trace"]["x"], rtol=0,
                               atol=0.5 * float(np.spacing(np.float32(np.abs(doc["trace"]["x"]).max()))))
    res = rrd_verify(rrd)
    assert res.returncode == 0, res.stderr


def test_lidar_run_records_scans_growing_map_and_safe_areas(tmp_path):
    """A --sensing lidar recording: the scan of every step, the sensed map (unknown / free /
    occupied) only when it changed, the safe areas as they grow, the corridor of every step."""
    from sanav_mj.eval.episode import run_scenario

    path = tmp_path / "lidar.rrd"
    out = run_scenario("single_rect", seed=0, sensing="lidar", rrd=path)
    ents = read_rrd(path)
    n = out.document["steps"]
    log = out.sensing_log
    scans = ents["/world/sensing/scan"]
    assert sorted(scans["steps"]) == list(range(n))  # one scan per control step
    order = np.argsort(scans["steps"])
    counts = [len(scans["data"]["Points2D:positions"][i]) for i in order]
    assert counts == [len(p) for p in log.scan_points] and sum(counts) > 0  # returns only
    frames = ents["/world/sensing/map"]
    assert sorted(frames["steps"]) == [k for k, _ in log.map_frames]
    assert 2 <= len(log.map_frames) <= n // log.every + 2 + out.document["replans"] + 1
    # each logged frame differs from the previous one, and the known area grows overall
    for (_, a), (_, b) in zip(log.map_frames, log.map_frames[1:]):
        assert not np.array_equal(a, b)
    assert (log.map_frames[-1][1] != 0).sum() > (log.map_frames[0][1] != 0).sum()
    assert sorted(ents["/world/sensing/safe_areas"]["steps"]) == [k for k, _ in log.area_frames]
    assert sorted(ents["/world/sensing/corridor"]["steps"]) == list(range(n))
    assert len(ents["/plots/timing/map_update_ms"]["steps"]) == n
    assert len(ents["/sensing/replans"]["steps"]) == out.document["replans"] + 1
    assert rrd_verify(path).returncode == 0
