"""Locate the files shipped with the package: the robot model and the built-in scenarios.

In a wheel they live inside the package (``sanav_mj/models``, ``sanav_mj/scenarios``); in a
source checkout or an editable install they are the top-level ``models/`` and ``scenarios/``
folders beside the package. Both layouts keep ``scenarios/`` and ``models/`` siblings, so a
scenario's ``<include file="../models/diff_drive.xml"/>`` resolves in either.
"""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parent


def _data_dir(name: str) -> Path:
    for candidate in (_PKG / name, _PKG.parent / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"sanav_mj data folder {name!r} not found beside {_PKG}")


def models_dir() -> Path:
    """Folder holding ``diff_drive.xml``."""
    return _data_dir("models")


def scenarios_dir() -> Path:
    """Folder holding the built-in scenario MJCF files."""
    return _data_dir("scenarios")


def robot_model_path() -> Path:
    """Path of the robot MJCF, ``models/diff_drive.xml``."""
    return models_dir() / "diff_drive.xml"


def builtin_scenarios() -> list[str]:
    """Names of the built-in scenarios (file stems in ``scenarios/``), sorted."""
    return sorted(p.stem for p in scenarios_dir().glob("*.xml"))
