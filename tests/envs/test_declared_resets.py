"""``Resets(joint_noise=...)`` draws on the named hinge and slide joints only, and refuses the other joint types."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from torchtasks.envs import BatchedMujocoEnv, readings  # noqa: E402
from torchtasks.envs.models import model_path  # noqa: E402
from torchtasks.envs.mujoco_declaration import Noise, Resets  # noqa: E402

NUM_ENVS = 16


def test_joint_noise_draws_on_each_named_hinge_and_slide_joint_only() -> None:
    """The arm has two hinges and two slides: uniform noise of its own width on each named one (a hinge and a
    slide), the keyframe's value on the others, a different draw per env."""
    widths = {"elbow": 0.5, "target_y": 0.1}  # a hinge and a slide
    env = BatchedMujocoEnv(
        model_path("arm"),
        NUM_ENVS,
        observation=readings.joint_pos(),
        resets=Resets(keyframe="home", joint_noise={name: Noise("uniform", width) for name, width in widths.items()}),
        seed=0,
    )
    qpos = env.reset()["observation"].numpy()
    home = env.model.key_qpos[0]
    for joint in ("shoulder", "elbow", "target_x", "target_y"):
        column = qpos[:, env.model.joint(joint).qposadr[0]]
        offset = column - home[env.model.joint(joint).qposadr[0]]
        if joint in widths:
            assert np.all(np.abs(offset) <= widths[joint]) and len(np.unique(column)) == NUM_ENVS, joint
        else:
            assert np.array_equal(offset, np.zeros(NUM_ENVS)), joint
    env.close()


def test_joint_noise_refuses_a_free_joint() -> None:
    with pytest.raises(ValueError, match="joint 'root' is not a hinge or slide joint"):
        BatchedMujocoEnv(
            model_path("quadruped"),
            2,
            observation=readings.joint_pos(),
            resets=Resets(joint_noise={"root": Noise("uniform", 0.1)}),
        )
