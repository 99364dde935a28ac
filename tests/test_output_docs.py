"""docs/outputs.md documents exactly the keys of the ``run --json`` and ``areas --json`` documents."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "outputs.md"

#: values documented as one leaf although they are objects (free-form keys)
LEAVES = {"mismatch", "plan.info"}


def _documented(section: str) -> set[str]:
    """The keys in the first column of the table under the ``## `section` `` heading."""
    text = DOC.read_text()
    m = re.search(rf"^## `{re.escape(section)}`\n(.*?)(?=^## )", text, flags=re.S | re.M)
    assert m, f"docs/outputs.md: no section {section!r}"
    keys = re.findall(r"^\| `([^`]+)` \|", m.group(1), flags=re.M)
    assert len(keys) == len(set(keys)), "a key documented twice"
    return set(keys)


def _keys(doc: dict, prefix: str = "") -> set[str]:
    """Keys of ``doc``, nested objects as ``outer.inner`` (those in :data:`LEAVES` as one key)."""
    out = set()
    for k, v in doc.items():
        name = prefix + k
        if isinstance(v, dict) and name not in LEAVES:
            out |= _keys(v, name + ".")
        else:
            out.add(name)
    return out


@pytest.mark.parametrize("mismatch", [None, {"delay": 1}])
def test_the_documented_run_keys_are_those_of_a_real_run(mismatch):
    import sanav_mj

    doc = sanav_mj.run_scenario("single_rect", controller="dwa", seed=1, mismatch=mismatch, time_limit_s=0.3).to_dict()
    assert _documented("run --json") == _keys(doc)


def test_the_documented_areas_keys_are_those_of_a_real_areas_document():
    from sanav_mj.eval.prepare import areas_document, prepare

    assert _documented("areas --json") == _keys(areas_document(prepare("u_shape")))


def test_the_helper_sees_a_missing_or_extra_key():
    """The comparison is not vacuous: the documented set is large and a changed document differs."""
    documented = _documented("run --json")
    assert {"solve_ms.p99", "trace.w", "min_clearance_m", "mismatch"} <= documented and len(documented) > 25
    assert _keys({"solve_ms": {"p99": 1.0}, "mismatch": {"delay": 1}, "x": 0}) == {"solve_ms.p99", "mismatch", "x"}
