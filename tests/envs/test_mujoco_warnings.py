"""MuJoCo's warnings: no MUJOCO_LOG.TXT in the user's directory, no console lines from torchtasks' own model loading."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import mujoco
import pytest

from torchtasks.envs._mujoco_log import MujocoWarning, route_mujoco_warnings

SCRIPT = """
from torchtasks.envs.locomotion import gymnasium_env
for env_id in ("HalfCheetah-v5", "Hopper-v5"):
    env = gymnasium_env(env_id, num_envs=2, seed=0)
    env.rollout(3)
    env.close()
print("done")
"""


def test_building_presets_prints_nothing_and_writes_no_log(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-c", SCRIPT], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "done"
    assert "settotalmass" not in result.stderr and "WARNING" not in result.stderr, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_other_mujoco_warnings_reach_python_warnings() -> None:
    route_mujoco_warnings()
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>"
    )
    data = mujoco.MjData(model)
    data.qacc_warmstart[:] = float("nan")
    data.qvel[:] = float("nan")  # MuJoCo warns of a bad qvel and resets the data
    with pytest.warns(MujocoWarning, match="MuJoCo: .*"):
        mujoco.mj_step(model, data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mujoco.mj_step(model, data)  # a healthy step warns of nothing
