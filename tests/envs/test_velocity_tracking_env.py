"""velocity_tracking_env: its entries, specs and names, the task's terms and end conditions in the data, and a
perturbation transform that reaches the policy's entries but not the task state."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("mujoco")

from torchrl.envs import ClipTransform

from torchtasks.domain import UniformDomainParam
from torchtasks.envs import velocity_tracking_env, velocity_tracking_perturbations
from torchtasks.envs.velocity_tracking import POLICY_KEYS
from torchtasks.tasks import VELOCITY_TRACKING_WEIGHTS, velocity_tracking_state
from torchtasks.transforms import DomainRandomization, EntryNoise, ObservationNoise

SIZES = {"lin_vel": 3, "ang_vel": 3, "gravity": 3, "command": 3, "joint_pos": 12, "joint_vel": 12, "last_action": 12}


def test_entries_specs_and_names():
    env = velocity_tracking_env(2, seed=0, perturbations=[ClipTransform(in_keys=["joint_vel"], low=-1e-3, high=1e-3)])
    spec = env.observation_spec
    assert {key: spec[key].shape[-1] for key in POLICY_KEYS} == SIZES
    assert spec["observation"].shape == (2, sum(SIZES.values()))
    layout = velocity_tracking_state(num_joints=12, num_feet=4, num_undesired=4)
    assert {key: spec[key].shape[-1] for key in layout} == {key: len(labels) for key, labels in layout.items()}
    assert spec["command"].space.low[0].tolist() == [-1.0, -0.5, -1.0]
    assert env.action_spec.shape == (2, 12)
    data = env.rollout(4, break_when_any_done=False)
    offsets = torch.tensor([0, *SIZES.values()]).cumsum(0).tolist()
    for i, key in enumerate(POLICY_KEYS):  # the observation is the policy entries, concatenated in this order
        assert torch.equal(data["observation"][..., offsets[i] : offsets[i + 1]], data[key].to(data["observation"]))
    assert (data["next", "joint_vel"].abs() <= 1.0001e-3).all()  # the perturbation reached the policy's entries...
    assert torch.equal(data["next", "lin_vel"], data["next", "base_lin_vel"])  # ...and not the task state
    assert set(VELOCITY_TRACKING_WEIGHTS) <= set(data["next", "task_reward"].keys())
    assert set(data["next", "ended_by"].keys()) == {"out_of_bounds", "base_contact", "bad_orientation"}
    assert data["gravity"][:, 0, 2].tolist() == pytest.approx([-1.0, -1.0], abs=1e-2)  # reset standing at home
    env.close()


def test_observation_noise_and_an_action_delay_plug_in():
    """ObservationNoise on a policy entry among the perturbations, an action delay drawn per env by
    DomainRandomization: the policy sees noisy joint velocities, the task the true ones; the physics ran the delayed
    action, the data holds the policy's."""
    noise = ObservationNoise({"joint_vel": EntryNoise(std=0.5)}, seed=0)
    delay = DomainRandomization([UniformDomainParam("action_delay", 2, 0, roundint=True)], when="reset", seed=0)
    env = velocity_tracking_env(2, seed=0, max_action_delay=2, perturbations=[noise, delay])
    data = env.rollout(3, break_when_any_done=False)
    assert data["domain", "action_delay"].flatten().tolist() == [2] * 6
    assert not torch.equal(data["next", "applied_action"], data["action"])  # zeros while the queue fills
    noisy = data["next", "joint_vel"]
    offset = data["next", "observation"][..., 24:36] - noisy.to(data["next", "observation"])
    assert offset.abs().max() == 0  # the observation is built from the noisy entry
    assert env.base_env.max_action_delay == 2
    env.close()


def test_bad_builder_arguments_are_refused():
    with pytest.raises(TypeError, match=r"perturbations\[0\] must be a torchrl Transform"):
        velocity_tracking_env(1, seed=0, perturbations=[object()])
    with pytest.raises(ValueError, match="command_low and command_high must have 3 entries"):
        velocity_tracking_env(1, seed=0, command_low=[-1.0, 0.0], command_high=[1.0, 0.0])
    # the function instead of what it returns
    with pytest.raises(TypeError, match=r"perturbations must be a sequence of torchrl Transforms .* got function"):
        velocity_tracking_env(1, seed=0, perturbations=velocity_tracking_perturbations)
    with pytest.raises(TypeError, match="velocity_tracking_perturbations: seed must be an int, got None"):
        velocity_tracking_perturbations(seed=None)
    with pytest.raises(TypeError, match="push_interval must be a pair"):
        velocity_tracking_perturbations(seed=0, push_interval=5.0)
    with pytest.raises(ValueError, match="push_interval must satisfy low <= high"):
        velocity_tracking_perturbations(seed=0, push_interval=(10.0, 5.0))


def test_the_perturbations_drawn_at_startup_keep_each_envs_values_over_its_resets():
    """``when="startup"``: each env's delay and gains drawn at its first reset and kept; ``"reset"``: new ones."""
    kept, redrawn = (
        velocity_tracking_env(
            8,
            seed=0,
            max_steps=3,
            max_action_delay=1,
            perturbations=velocity_tracking_perturbations(seed=0, noise=False, pushes=False, when=when),
        )
        for when in ("startup", "reset")
    )
    for env, same in ((kept, True), (redrawn, False)):
        data = env.rollout(7, break_when_any_done=False)  # resets after steps 3 and 6
        gains = data["next", "domain", "actuator_kp_scale"][..., 0]
        assert (gains.std(0) > 0).all()  # drawn per env
        assert bool((gains == gains[:, :1]).all()) is same
        env.close()
    with pytest.raises(ValueError, match="when must be 'reset' or 'startup', got 'interval'"):
        velocity_tracking_perturbations(seed=0, when="interval")
