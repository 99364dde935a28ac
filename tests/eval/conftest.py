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
