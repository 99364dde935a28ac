"""Tests of sanav_mj.eval.plots: each figure is a non-empty PNG of the expected pixel size,
and inconsistent input is a clear error."""

from __future__ import annotations

import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from _helpers import make_prep

from sanav_mj.eval.outcome import RunOutcome
from sanav_mj.eval.prepare import Prepared
from sanav_mj.eval import plots
from sanav_mj.eval.plots import plot_areas, plot_heatmap, plot_run, plot_success_bars, run_reference
from sanav_mj.mapping.quadtree import QuadtreeLeaves
from sanav_mj.planning.reference import Plan
from sanav_mj.sim.runner import Episode, EpisodeTrace


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) from the PNG header; fails on anything that is not a PNG."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def png_pixels(path: Path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(path)


def assert_png(path: Path, size: tuple[int, int]) -> None:
    assert path.is_file() and path.stat().st_size > 5000
    assert png_size(path) == size
    img = png_pixels(path)
    assert img.std() > 0.01, "blank image"


@pytest.fixture(scope="module")
def prep() -> Prepared:
    return make_prep(post="capsule")


def make_trace(n: int = 25) -> EpisodeTrace:
    tr = EpisodeTrace()
    for k in range(n):
        pose = np.array([4.0 * k / n, -0.8 * np.sin(np.pi * k / n), -0.5 + 0.05 * k])
        tr.t.append(0.1 * k)
        tr.pose.append(pose)
        tr.measured.append(pose)
        tr.cmd.append((0.6, 0.2 - 0.01 * k))
        tr.applied.append((0.6, 0.2))
        tr.velocity.append(np.array([0.5 + 0.01 * k, 0.15]))
        tr.wheel_cmd.append(np.array([5.0, 6.0]))
        tr.wheel_speed.append(np.array([5.0, 6.0]))
        tr.solve_ms.append(2.0)
        tr.pipeline_ms.append(2.5)
        tr.status.append("ok")
        tr.ok.append(True)
        tr.clearance.append(0.4)
        tr.contacts.append(1 if k == n - 1 else 0)
        tr.predicted.append(None)
        tr.rect_ids.append(None)
        tr.margins.append(None)
    return tr


def outcome_of(prep: Prepared, tr: EpisodeTrace) -> RunOutcome:
    ep = Episode(False, "collision", len(tr), 0.1 * len(tr), 1, 0, np.array([4.0, 0.0, 0.7]), tr, 0.3)
    doc = {"seed": 3, "path_length_m": 4.8, "min_clearance_m": 0.0}
    return RunOutcome(prep, "sa-mpc", np.array([0.0, 0.0, -0.5]), ep, doc)


# ---------------------------------------------------------------------------- plot_areas
def test_plot_areas_png(prep, tmp_path):
    out = plot_areas(prep, tmp_path / "sub" / "areas.png")
    assert out == tmp_path / "sub" / "areas.png"
    assert_png(out, (1500, 900))


def test_plot_areas_dpi_scales_the_image(prep, tmp_path):
    assert_png(plot_areas(prep, tmp_path / "a.png", dpi=50), (750, 450))


def test_plot_areas_rejects_inconsistent_leaves(prep, tmp_path):
    bad_leaves = QuadtreeLeaves(prep.leaves.boxes, np.ones(4, dtype=bool), prep.leaves.depth)
    bad = replace(prep, map=replace(prep.map, leaves=bad_leaves))
    with pytest.raises(ValueError, match="leaves: boxes"):
        plot_areas(bad, tmp_path / "bad.png")
    assert not (tmp_path / "bad.png").exists()


def test_plot_areas_rejects_out_of_range_corridor(prep, tmp_path):
    p = prep.plan
    plan = Plan(True, "ok", np.array([0, 7]), p.goal, p.waypoints, p.path, p.smoothed, p.reference)
    bad = replace(prep, plan=plan)
    with pytest.raises(ValueError, match="plan.corridor"):
        plot_areas(bad, tmp_path / "bad.png")


def test_plot_areas_without_a_plan(prep, tmp_path):
    empty = np.zeros((0, 2))
    plan = Plan(False, "no_path", np.zeros(0, dtype=int), np.array([4.0, 0.0]), empty, empty, empty, None)
    p = replace(prep, plan=plan)
    assert_png(plot_areas(p, tmp_path / "noplan.png"), (1500, 900))


# ---------------------------------------------------------------------------- plot_run
def test_plot_run_png(prep, tmp_path):
    assert_png(plot_run(outcome_of(prep, make_trace()), tmp_path / "run.png"), (1500, 750))


def test_plot_run_of_an_empty_episode(prep, tmp_path):
    """A no_path run has no steps; the figure still shows the map, start and goal."""
    assert_png(plot_run(outcome_of(prep, EpisodeTrace()), tmp_path / "empty.png"), (1500, 750))


def test_plot_run_rejects_a_ragged_trace(prep, tmp_path):
    tr = make_trace()
    tr.cmd.pop()
    with pytest.raises(ValueError, match="equal lengths"):
        plot_run(outcome_of(prep, tr), tmp_path / "bad.png")


def test_plot_run_rejects_bad_footprint_count(prep, tmp_path):
    with pytest.raises(ValueError, match="n_footprints"):
        plot_run(outcome_of(prep, make_trace()), tmp_path / "bad.png", n_footprints=-1)


# ---------------------------------------------------------------------------- plot_success_bars
ROWS = [
    {"scenario": s, "controller": c, "success_rate": r}
    for s, rs in (("single", (100, 90, 80, 60)), ("u_shape", (100, 30, 20, 40)), ("complex", (90, 10, 0, 20)))
    for c, r in zip(("sa-mpc", "mpc", "dwa", "dqn"), rs)
]


def test_plot_success_bars_png(tmp_path):
    assert_png(plot_success_bars(ROWS, tmp_path / "bars.png"), (1200, 600))


def test_plot_success_bars_with_a_missing_pair(tmp_path):
    assert_png(plot_success_bars(ROWS[:-1], tmp_path / "gap.png"), (1200, 600))


@pytest.mark.parametrize(
    "rows, match",
    [
        ([], "at least one"),
        ([{"scenario": "a", "controller": "b"}], "missing key 'success_rate'"),
        ([{"scenario": "a", "controller": "b", "success_rate": 1.5e2}], r"\[0, 100\]"),
        ([{"scenario": "a", "controller": "b", "success_rate": float("nan")}], r"\[0, 100\]"),
        ([{"scenario": "a", "controller": "b", "success_rate": 50}] * 2, "duplicate pair"),
    ],
)
def test_plot_success_bars_rejects_bad_rows(rows, match, tmp_path):
    with pytest.raises(ValueError, match=match):
        plot_success_bars(rows, tmp_path / "bad.png")


# ---------------------------------------------------------------------------- plot_heatmap
def test_plot_heatmap_2d_png(tmp_path):
    vals = np.array([[100.0, 80.0, 40.0], [90.0, np.nan, 20.0]])
    out = plot_heatmap(vals, "wheel_radius", ["0.9", "1.0", "1.1"], "delay", ["0", "2"], "sa-mpc: success rate [%]",
                       tmp_path / "h.png")
    assert_png(out, (900, 700))


def test_plot_heatmap_1d_png(tmp_path):
    """The robustness runner's 1-D call: y_key "" with a single placeholder label."""
    vals = np.array([[0.12, 0.08, np.inf]])
    out = plot_heatmap(vals, "friction", ["0.3", "0.6", "1.0"], "", [""], "sa-mpc: min clearance [m]",
                       tmp_path / "l.png")
    assert_png(out, (900, 500))


def test_plot_heatmap_1d_accepts_flat_values(tmp_path):
    assert_png(plot_heatmap([1.0, 2.0], "k", [1, 2], None, None, "t", tmp_path / "f.png"), (900, 500))


@pytest.mark.parametrize(
    "vals, y_key, y_values, match",
    [
        (np.zeros((3, 2)), "delay", ["0", "2"], r"expected shape .* = \(2, 3\), got \(3, 2\)"),
        (np.zeros((2, 3)), "delay", [], "y_values"),
        (np.zeros(4), "", [""], "1-D sweep"),
        (np.zeros((2, 3)), "", [""], "1-D sweep"),
    ],
)
def test_plot_heatmap_rejects_mismatched_shapes(vals, y_key, y_values, match, tmp_path):
    with pytest.raises(ValueError, match=match):
        plot_heatmap(vals, "wheel_radius", ["0.9", "1.0", "1.1"], y_key, y_values, "t", tmp_path / "bad.png")


def test_plot_heatmap_rejects_empty_x(tmp_path):
    with pytest.raises(ValueError, match="x_values"):
        plot_heatmap(np.zeros((1, 0)), "k", [], "j", ["a"], "t", tmp_path / "bad.png")


# ---------------------------------------------------------------------------- end to end
def test_plots_of_a_real_run(tmp_path):
    """Through the whole pipeline: a short u_shape run and its map."""
    from sanav_mj.eval.episode import run_scenario

    out = run_scenario("u_shape", seed=2, time_limit_s=2.0)
    assert len(out.episode.trace) > 5
    assert_png(plot_run(out, tmp_path / "run.png"), (1500, 750))
    assert_png(plot_areas(out.prepared, tmp_path / "areas.png"), (1500, 900))


# ---------------------------------------------------------------------------- what each controller tracked
def _as(outcome: RunOutcome, controller: str) -> RunOutcome:
    return RunOutcome(outcome.prepared, controller, outcome.start, outcome.episode, outcome.document)


def test_run_reference_of_sa_mpc_is_the_plan(prep):
    ref = run_reference(outcome_of(prep, make_trace()))
    assert ref.label == "reference (safe-area corridor)" and ref.origins.shape == (0, 2)
    assert len(ref.paths) == 1
    np.testing.assert_array_equal(ref.paths[0], prep.plan.reference.states[:, :2])


def test_run_reference_of_sa_mpc_without_a_plan(prep):
    from dataclasses import replace

    no_plan = replace(prep, plan=Plan(False, "no_path", np.zeros(0, int), np.array([4.0, 0.0]), np.zeros((0, 2)),
                                      np.zeros((0, 2)), np.zeros((0, 2)), None))
    ref = run_reference(outcome_of(no_plan, make_trace()))
    assert ref.paths == [] and ref.label == "no reference path (planning: no_path)"


def test_run_reference_of_the_penalty_mpc_known_answers(prep):
    out = _as(outcome_of(prep, make_trace()), "mpc")
    ref = run_reference(out, [0, 10, 99])  # step 99 is past the end of the 25-step trace
    assert len(ref.paths) == 2 and "straight to the goal from 3 m ahead" in ref.label
    # step 0: measured (0, 0), goal (4, 0); the fixture robot's MPC v_max is 2 - 3 * 0.19 = 1.43 m/s,
    # the reference runs at 0.8 of it: sample k at min(3 + 0.1144 k, 4) m along x
    s = np.minimum(3.0 + 0.8 * 1.43 * 0.1 * np.arange(21), 4.0)
    np.testing.assert_allclose(ref.paths[0], np.column_stack((s, np.zeros(21))), atol=1e-12)
    # step 10: measured (1.6, -0.8 sin(0.4 pi)), 2.52 m from the goal, less than the lookahead:
    # every sample sits on the goal
    np.testing.assert_allclose(ref.paths[1], np.tile([4.0, 0.0], (21, 1)), atol=1e-12)
    np.testing.assert_allclose(ref.origins, [[0.0, 0.0], [1.6, -0.8 * np.sin(0.4 * np.pi)]], atol=1e-12)


def test_run_reference_of_the_penalty_mpc_is_the_controllers(prep):
    """The drawn segment equals what a PenaltyMPC as built by make_controller("mpc") tracks."""
    from sanav_mj.control.penalty_mpc import PenaltyMPC

    sc = prep.scenario
    ctl = PenaltyMPC(sc.robot, sc.obstacles, prep.grid.inflation, sc.goal)
    tr = make_trace()
    ref = run_reference(_as(outcome_of(prep, tr), "mpc"), range(0, 25, 4))
    assert len(ref.paths) == 7
    for k, line in zip(range(0, 25, 4), ref.paths):
        np.testing.assert_allclose(line, ctl.reference(tr.measured[k])[0][:, :2], atol=1e-12)


@pytest.mark.parametrize("controller, fragment", [("dwa", "DWA"), ("dqn", "DQN"), ("ppo", "'ppo'")])
def test_run_reference_of_controllers_without_one(prep, controller, fragment):
    ref = run_reference(_as(outcome_of(prep, make_trace()), controller))
    assert ref.paths == [] and ref.label.startswith("no reference path") and fragment in ref.label


def _drawn_map(monkeypatch, outcome, tmp_path):
    """plot_run's map axes (the figure is captured instead of saved)."""
    figs = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figs.append(fig) or Path(path))
    plot_run(outcome, tmp_path / "run.png")
    ax = figs[0].axes[0]
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    blue = [ln for ln in ax.get_lines() if ln.get_color() == plots._SMOOTH and ln.get_linestyle() == "-"]
    return legend, blue


@pytest.mark.parametrize("controller", ["sa-mpc", "mpc", "dwa", "dqn"])
def test_plot_run_draws_what_each_controller_tracked(prep, tmp_path, monkeypatch, controller):
    out = _as(outcome_of(prep, make_trace()), controller)
    legend, blue = _drawn_map(monkeypatch, out, tmp_path)
    want = run_reference(out, [0, 5, 10, 14, 19, 24])  # the footprint steps of 25 steps, 6 footprints
    assert want.label in legend
    assert len(blue) == len(want.paths)
    for line, path in zip(blue, want.paths):
        np.testing.assert_allclose(line.get_xydata(), path)
    if controller in ("dwa", "dqn"):
        assert blue == [] and not any("reference (" in t for t in legend)


def test_figure_format_from_the_extension():
    from sanav_mj.eval.plots import figure_format

    assert [figure_format(p) for p in ("a.png", "b.PDF", "c.svg", "/dev/stdout")] == ["png", "pdf", "svg", "png"]
    with pytest.raises(ValueError, match=r"r\.txt: expected a figure file ending in one of .*\.pdf.* got '\.txt'"):
        figure_format("r.txt")


def test_plot_heatmap_pdf_and_svg_and_no_partial_file(tmp_path, monkeypatch):
    for name, magic in (("h.pdf", b"%PDF"), ("h.svg", b"<?xml")):
        out = plot_heatmap(np.eye(2), "mass", [1, 2], "delay", [0, 1], "u_shape / sa-mpc: success rate [%]",
                           tmp_path / name)
        assert out.read_bytes()[: len(magic)] == magic
    from matplotlib.figure import Figure

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(Figure, "savefig", interrupted)
    with pytest.raises(KeyboardInterrupt):
        plot_heatmap(np.eye(2), "mass", [1, 2], "delay", [0, 1], "t", tmp_path / "cut.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.pdf", "h.svg"]


def test_run_reference_of_the_penalty_mpc_uses_the_runs_spec(prep):
    """The segment follows the settings the run had (its ControllerSpec), not the defaults."""
    from dataclasses import replace as dc_replace

    from sanav_mj.control.config import PenaltyConfig
    from sanav_mj.control.spec import ControllerSpec

    spec = ControllerSpec("mpc", penalty=PenaltyConfig(lookahead=1.0, reference_speed=0.5))
    out = dc_replace(_as(outcome_of(prep, make_trace()), "mpc"), spec=spec)
    ref = run_reference(out, [0])
    assert "from 1 m ahead" in ref.label
    s = np.minimum(1.0 + 0.5 * 0.1 * np.arange(21), 4.0)  # measured (0, 0), goal (4, 0)
    np.testing.assert_allclose(ref.paths[0], np.column_stack((s, np.zeros(21))), atol=1e-12)
