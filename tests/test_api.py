"""The public Python API: exports, the run document equals the CLI's, errors, docs/api.md runs."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sanav_mj
from sanav_mj.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
WALL_CLOCK = ("solve_ms", "pipeline_ms", "timing")


def strip_wall_clock(doc):
    if isinstance(doc, dict):
        return {k: strip_wall_clock(v) for k, v in doc.items() if not k.startswith(WALL_CLOCK)}
    if isinstance(doc, list):
        return [strip_wall_clock(v) for v in doc]
    return doc


def test_package_exports_the_api():
    for name in ("load_scenario", "build_map", "plan", "run_scenario", "Mismatch"):
        assert name in dir(sanav_mj) and callable(getattr(sanav_mj, name))
    from sanav_mj.sim.mismatch import Mismatch

    assert sanav_mj.Mismatch is Mismatch
    with pytest.raises(AttributeError, match="no_such_name"):
        sanav_mj.no_such_name  # noqa: B018


def test_import_is_light():
    """``import sanav_mj`` loads neither MuJoCo nor CasADi (the API is imported on first use)."""
    code = "import sys, sanav_mj; print(sorted(m for m in ('mujoco', 'casadi', 'torch', 'sanav_mj.api') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_build_map_rects_are_the_areas_document_rects(tmp_path):
    m = sanav_mj.build_map("u_shape")
    assert m.rects.shape[1] == 4 and m.rects.dtype == float
    assert cli_main(["areas", "u_shape", "--json", str(tmp_path / "a.json")]) == 0
    doc = json.loads((tmp_path / "a.json").read_text())
    np.testing.assert_array_equal(m.rects, np.asarray(doc["rects"]))


def test_plan_matches_the_areas_document(tmp_path):
    sc = sanav_mj.load_scenario("double_rect")
    p = sanav_mj.plan(sc)
    assert cli_main(["areas", "double_rect", "--json", str(tmp_path / "a.json")]) == 0
    doc = json.loads((tmp_path / "a.json").read_text())
    assert p.ok and p.corridor.tolist() == doc["corridor"]
    np.testing.assert_array_equal(p.reference.states.round(6), np.asarray(doc["reference"]))


def test_run_document_is_the_cli_json(tmp_path):
    """``run_scenario(...).to_dict()`` equals what ``run --json`` writes (a dict mismatch
    against ``--mismatch``), apart from the wall-clock fields."""
    out = tmp_path / "run.json"
    code = cli_main(["run", "single_rect", "--seed", "3", "--mismatch", "delay=1", "pos_noise=0.01",
                     "--json", str(out)])
    res = sanav_mj.run_scenario("single_rect", seed=3, mismatch={"delay": 1, "pos_noise": 0.01})
    doc = res.to_dict()
    written = json.loads(out.read_text())
    assert code == (0 if res.success else 1)
    assert set(doc) == set(written)
    assert strip_wall_clock(json.loads(json.dumps(doc))) == strip_wall_clock(written)
    assert doc["mismatch"] == {"delay": 1, "pos_noise": 0.01}
    assert res.reason == doc["reason"] and res.start.shape == (3,)
    doc["trace"]["x"].clear()  # to_dict() hands out a copy
    assert res.to_dict()["trace"]["x"]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"controller": "ppo"}, "controller"),
        ({"seed": -1}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"mismatch": {"bogus": 1}}, "mismatch: unknown key 'bogus'"),
        ({"mismatch": {"wheel_radius": 3.0}}, "wheel_radius"),
        ({"mismatch": ["delay=1"]}, "mismatch"),
        ({"resolution": 0.0}, "resolution"),
        ({"time_limit_s": float("nan")}, "time_limit_s"),
        ({"yaw": float("inf")}, "yaw"),
    ],
)
def test_bad_arguments_name_the_argument(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        sanav_mj.run_scenario("single_rect", **kwargs)


def test_bad_scenario_and_map_arguments():
    from sanav_mj.scene import ScenarioError

    with pytest.raises(ScenarioError, match="no_such_scenario"):
        sanav_mj.load_scenario("no_such_scenario")
    with pytest.raises(TypeError, match="scenario"):
        sanav_mj.build_map(42)
    with pytest.raises(ValueError, match="merge"):
        sanav_mj.build_map("u_shape", merge="greedy?")
    with pytest.raises(ValueError, match="start"):
        sanav_mj.plan("u_shape", start=[0.0, 0.0])


def python_blocks(markdown: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", markdown, flags=re.S | re.M)


def test_docs_api_example_runs(capsys):
    """Every ```python block of docs/api.md, in order, in one namespace (as a notebook)."""
    blocks = python_blocks((ROOT / "docs" / "api.md").read_text())
    assert len(blocks) >= 5
    if any("gymnasium" in b for b in blocks):
        pytest.importorskip("gymnasium")
    namespace: dict = {"__name__": "docs_api"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/api.md block {i + 1}", "exec"), namespace)
    assert namespace["result"].success
    assert "goal" in capsys.readouterr().out


def test_readme_python_section_runs(capsys):
    text = (ROOT / "README.md").read_text()
    blocks = python_blocks(text)
    assert len(blocks) == 1
    exec(compile(blocks[0], "README.md python block", "exec"), {"__name__": "readme"})
    assert capsys.readouterr().out.strip()


def test_lidar_run_document_is_the_cli_json(tmp_path):
    """``sensing="lidar"`` gives the ``run --sensing lidar --json`` document (deterministic for a
    seed apart from the wall-clock fields), with its sensing fields."""
    out = tmp_path / "run.json"
    code = cli_main(["run", "single_rect", "--seed", "1", "--sensing", "lidar", "--json", str(out)])
    doc = sanav_mj.run_scenario("single_rect", seed=1, sensing="lidar").to_dict()
    written = json.loads(out.read_text())
    assert code == 0 and doc["success"]
    assert set(doc) == set(written) and {"sensing", "map_update_ms", "replans"} <= set(doc)
    def strip(d):  # map_update_ms is wall clock too
        return {k: v for k, v in strip_wall_clock(d).items() if k != "map_update_ms"}

    assert strip(json.loads(json.dumps(doc))) == strip(written)
    assert doc["sensing"] == "lidar" and doc["replans"] == written["replans"]


def test_lidar_run_with_the_discs_footprint():
    """``sensing="lidar"`` with a discs-mode ControllerSpec: the sensed map is inflated by the
    disc cover's radius + footprint_margin and the document names the footprint settings (one
    grid of 0.05 / refine m cells, the chain grown by grow_m); the pose route is refused."""
    from dataclasses import replace

    from sanav_mj.control.config import MPCConfig
    from sanav_mj.control.spec import ControllerSpec

    spec = ControllerSpec("sa-mpc", replace(MPCConfig(), footprint="discs", footprint_margin=0.05))
    res = sanav_mj.run_scenario("single_rect", controller=spec, seed=1, sensing="lidar")
    doc = res.to_dict()
    assert doc["success"] and doc["collisions"] == 0 and doc["sensing"] == "lidar"
    mpc = spec.sa_mpc
    assert doc["footprint"] == {"mode": "discs", "discs": 3, "margin_m": 0.05, "route": "corridor",
                                "refine": mpc.footprint_refine, "grow_m": mpc.footprint_grow, "open_speed": mpc.footprint_open_speed}
    fp = sanav_mj.footprint.robot_footprint(res.prepared.scenario.model)
    assert res.sensed.map.grid.inflation == fp.discs(3)[1] + 0.05
    # one grid of 0.05 / footprint_refine m cells, the chain grown into its safe cells
    assert res.sensed.map.grid.resolution == 0.05 / mpc.footprint_refine
    assert res.sensed.config.grow == mpc.footprint_grow
    with pytest.raises(ValueError, match="footprint_route"):
        sanav_mj.run_scenario("single_rect", controller=replace(spec, sa_mpc=replace(spec.sa_mpc, footprint_route="pose")),
                              sensing="lidar")


@pytest.mark.parametrize("kwargs, match", [
    ({"sensing": "radar"}, "sensing"),
    ({"sensing": "lidar", "controller": "dwa"}, "sa-mpc"),
])
def test_bad_sensing_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sanav_mj.run_scenario("single_rect", **kwargs)


def test_controller_spec_is_public_and_drives_the_run():
    """A ControllerSpec given to run_scenario is the one the controller uses: the default spec
    gives the same document as the name, a spec with another horizon gives another trace."""
    from dataclasses import replace

    from sanav_mj.control.config import MPCConfig
    from sanav_mj.control.spec import ControllerSpec

    assert sanav_mj.ControllerSpec is ControllerSpec
    assert callable(sanav_mj.run_bench) and callable(sanav_mj.run_robustness)
    kw = dict(seed=0, time_limit_s=3.0)
    by_name = sanav_mj.run_scenario("single_rect", controller="sa-mpc", **kw).to_dict()
    by_spec = sanav_mj.run_scenario("single_rect", controller=ControllerSpec("sa-mpc"), **kw).to_dict()
    assert strip_wall_clock(by_spec) == strip_wall_clock(by_name)
    slow = ControllerSpec("sa-mpc", sa_mpc=replace(MPCConfig(), v_max=0.3))
    other = sanav_mj.run_scenario("single_rect", controller=slow, **kw).to_dict()
    assert max(other["trace"]["v"]) <= 0.3 + 1e-9 < max(by_name["trace"]["v"])
    with pytest.raises(ValueError, match="controller: expected one of .* or a ControllerSpec, got 'pid'"):
        sanav_mj.run_scenario("single_rect", controller="pid")
