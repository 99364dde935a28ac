"""Shared fixtures: scenario files written from scratch into a temporary folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from sanav_mj.resources import robot_model_path

#: a 12 m x 8 m floor centred at (4, 0): workspace x [-2, 10], y [-4, 4]
FLOOR = '<geom name="floor" type="plane" pos="4 0 0" size="6 4 0.1"/>'


def scenario_xml(world: str = "", start: str | None = "0 0 0", goal: str | None = "4 0",
                 include: str | None = None, floor: str = FLOOR, extra: str = "") -> str:
    """MJCF text of a scenario: robot include, start/goal numerics, ``floor`` + ``world`` geoms.

    ``include`` defaults to the absolute path of the packaged robot; ``start``/``goal`` None
    leave the numeric out; ``extra`` goes after </worldbody> (e.g. an <asset> block).
    """
    include = str(robot_model_path()) if include is None else include
    numerics = "".join(
        f'<numeric name="{n}" data="{v}"/>' for n, v in (("start", start), ("goal", goal)) if v is not None
    )
    custom = f"<custom>{numerics}</custom>" if numerics else ""
    return (f'<mujoco model="t">\n  <include file="{include}"/>\n  {custom}\n'
            f"  <worldbody>\n    {floor}\n{world}\n  </worldbody>\n{extra}\n</mujoco>\n")


@pytest.fixture
def write_scenario(tmp_path: Path):
    """Factory ``write_scenario(world="", name="s", **kw) -> Path`` (keywords of :func:`scenario_xml`)."""

    def write(world: str = "", name: str = "s", **kw) -> Path:
        path = tmp_path / f"{name}.xml"
        path.write_text(scenario_xml(world, **kw))
        return path

    return write


@pytest.fixture(scope="session")
def make_scenario_xml():
    """:func:`scenario_xml` itself, for module-scoped fixtures that write their own files."""
    return scenario_xml


@pytest.fixture
def fill_disk(monkeypatch):
    """Factory ``fill_disk(keep, ending="")``: from then on, writes to the temporary file
    (``.NAME.<random>.part``, see :mod:`sanav_mj.outputs`) of an output whose final NAME ends in
    ``ending`` (every output with "") stop with ENOSPC after ``keep`` characters: the first
    ``keep`` are written, the write that goes past them raises."""
    import builtins
    import errno

    from sanav_mj import outputs

    class Full:
        def __init__(self, fh, keep: int):
            self.fh, self.left = fh, keep

        def write(self, data):
            if len(data) > self.left:
                self.fh.write(data[:self.left])
                self.left = 0
                raise OSError(errno.ENOSPC, "No space left on device")
            self.left -= len(data)
            return self.fh.write(data)

        def __getattr__(self, attr):
            return getattr(self.fh, attr)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    def fill(keep: int, ending: str = "") -> None:
        def fake_open(path, mode="r", *a, **k):
            fh = builtins.open(path, mode, *a, **k)
            name = Path(path).name  # .NAME.<8 hex digits>.part
            final = name[1:].rsplit(".", 2)[0] if name.startswith(".") and name.endswith(".part") else None
            return Full(fh, keep) if "w" in mode and final is not None and final.endswith(ending) else fh

        monkeypatch.setattr(outputs, "open", fake_open, raising=False)

    return fill


@pytest.fixture
def fake_campaign_runs(monkeypatch):
    """Factory ``fake_campaign_runs(doc_of) -> list``: from then on the runs of a bench or
    robustness campaign (:func:`sanav_mj.eval.bench.stream_campaign`) are ``doc_of(job)`` (no simulation, no journal, no worker); the list
    gets every job, in order."""
    from sanav_mj.eval import bench

    def install(doc_of) -> list:
        seen = []

        def fake_run_jobs(jobs, workers, desc, **kw):
            seen.extend(jobs)
            return [doc_of(j) for j in jobs]

        monkeypatch.setattr(bench, "run_jobs", fake_run_jobs)
        return seen

    return install
