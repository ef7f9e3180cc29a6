"""MuJoCo models no one here wrote, for the tests: dm_control's suite XMLs and Gymnasium's assets, found on disk.

dm_control is found without importing it (it does not import on MuJoCo 4); a test whose model is absent is skipped
with the reason.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest


def _package_folder(package: str) -> Path | None:
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def dm_control_suite_xml(name: str) -> Path:
    """The path of dm_control's ``suite/<name>`` (e.g. ``"quadruped.xml"``); skips the test when it is absent."""
    folder = _package_folder("dm_control")
    path = None if folder is None else folder / "suite" / name
    if path is None or not path.is_file():
        pytest.skip(f"dm_control's suite/{name} is not installed (pip install dm_control to run this test)")
    return path


def gymnasium_asset(name: str) -> Path:
    """The path of Gymnasium's ``envs/mujoco/assets/<name>`` (e.g. ``"ant.xml"``); skips the test when absent."""
    folder = _package_folder("gymnasium")
    path = None if folder is None else folder / "envs" / "mujoco" / "assets" / name
    if path is None or not path.is_file():
        pytest.skip(f"Gymnasium's envs/mujoco/assets/{name} is not installed (pip install gymnasium[mujoco])")
    return path
