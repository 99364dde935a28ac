"""Fixtures of the eval tests."""

from __future__ import annotations

import pytest


@pytest.fixture
def ctrl_c_after(monkeypatch):
    """Factory ``ctrl_c_after(n, total=None) -> list``: from then on a campaign's progress bar
    raises KeyboardInterrupt (Ctrl-C in the parent) when the ``n``-th row has finished; the list
    gets one entry per finished row; ``total`` given: the bar must be made with that total."""
    from sanav_mj.eval import campaign

    def install(n: int, total: int | None = None) -> list[int]:
        finished: list[int] = []

        class Bar:
            def __init__(self, *a, **kw):
                if total is not None:
                    assert kw.get("total") == total

            def update(self, k=1):
                finished.append(k)
                if len(finished) == n:
                    raise KeyboardInterrupt

            def close(self):
                pass

        monkeypatch.setattr(campaign, "tqdm", Bar)
        return finished

    return install


@pytest.fixture
def endless_jobs():
    """Factory ``endless_jobs(total, time_limit_s) -> (jobs, taken)``: a lazy campaign of
    ``total`` jobs (far too many to list; single_rect / dwa, seeds 0, 1, ...) generated on
    demand; ``taken`` gets each seed as its job is taken."""
    from sanav_mj.eval.campaign import Job, JobSet

    def make_set(total: int, time_limit_s: float):
        taken: list[int] = []

        def make():
            k = 0
            while True:
                taken.append(k)
                yield Job("single_rect", "dwa", k, (), time_limit_s)
                k += 1

        return JobSet(make, total), taken

    return make_set
