"""scripts/bench_solvers.py: the replay minimum and the options (no timing asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "bench_solvers.py"


def _load():
    spec = importlib.util.spec_from_file_location("bench_solvers", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class _Echo:
    """A deterministic fake controller: the command is the observation (plus an offset)."""

    def __init__(self, offset=0.0):
        self.offset = offset
        self.resets = []

    def reset(self, pose):
        self.resets.append(np.array(pose))

    def step(self, obs):
        return SimpleNamespace(v=obs + self.offset, w=-obs)


def test_replay_min_replays_every_step_and_checks_the_commands():
    mod = _load()
    obs = [0.1, 0.2, 0.3]
    cmds = [SimpleNamespace(v=o, w=-o) for o in obs]
    made = []

    def make():
        made.append(_Echo())
        return made[-1]

    best = mod.replay_min(make, np.zeros(3), obs, cmds, 3)
    assert best.shape == (3,) and np.all(np.isfinite(best)) and np.all(best >= 0)
    assert len(made) == 3 and all(len(c.resets) == 1 for c in made)
    with pytest.raises(RuntimeError, match="replay step 0"):
        mod.replay_min(lambda: _Echo(offset=1e-12), np.zeros(3), obs, cmds, 1)


def test_mujoco_only_needs_mujoco(capsys):
    mod = _load()
    with pytest.raises(SystemExit) as e:
        mod.main(["--mujoco-only"])
    assert e.value.code == 2
    assert "--mujoco-only needs --mujoco" in capsys.readouterr().err
