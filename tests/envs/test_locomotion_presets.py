"""The locomotion presets and their reward terms: construction, validation, specs and batching.

Expected values come from Gymnasium's own env methods (``is_healthy``, ``contact_cost``,
``control_cost``, ``dt``) and from hand-computed numbers, never from the code under test. The
step-by-step reward parity with Gymnasium is in ``test_locomotion_parity.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")

from tensordict import TensorDict  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchtasks.envs.locomotion import (  # noqa: E402
    SUPPORTED_ENV_IDS,
    Float64InfoReader,
    MujocoStateInfo,
    gymnasium_env,
    locomotion_state_layout,
    locomotion_task,
    make_gymnasium_env,
)
from torchtasks.rewards.terms import (  # noqa: E402
    ContactCostReward,
    ControlCostReward,
    HealthyReward,
    VelocityReward,
)

ENV_IDS = ["HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Swimmer-v5", "Ant-v5", "Humanoid-v5"]
EXPECTED_TERMS = {
    "HalfCheetah-v5": ("forward", "ctrl"),
    "Hopper-v5": ("forward", "ctrl", "survive"),
    "Walker2d-v5": ("forward", "ctrl", "survive"),
    "Swimmer-v5": ("forward", "ctrl"),
    "Ant-v5": ("forward", "ctrl", "contact", "survive"),
    "Humanoid-v5": ("forward", "ctrl", "contact", "survive"),
}
HEALTH_ENVS = ["Hopper-v5", "Walker2d-v5", "Ant-v5", "Humanoid-v5"]

mujoco = pytest.mark.mujoco


# --------------------------------------------------------------------------------- reward terms
@pytest.mark.parametrize("batch_shape", [(), (3,), (2, 3)], ids=["unbatched", "B3", "B2x3"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
def test_terms_are_batched_and_follow_the_input_dtype(batch_shape: tuple[int, ...], dtype: torch.dtype) -> None:
    generator = torch.Generator().manual_seed(0)
    state = torch.randn((*batch_shape, 6), generator=generator, dtype=dtype)
    action = torch.randn((*batch_shape, 2), generator=generator, dtype=dtype)
    s, a = state.double().numpy(), action.double().numpy()
    expected = {
        "velocity": 1.25 * s[..., 2],
        "ctrl": -0.1 * (a**2).sum(-1),
        "healthy": 5.0 * ((s[..., 1] > -0.5) & (s[..., 1] < 0.5)),
        "contact": -np.minimum(0.5 * (np.clip(s[..., 3:], -1.0, 1.0) ** 2).sum(-1), 0.8),
    }
    terms = {
        "velocity": VelocityReward(1.25, index=2),
        "ctrl": ControlCostReward(0.1),
        "healthy": HealthyReward(5.0, index=1, low=-0.5, high=0.5),
        "contact": ContactCostReward(0.5, start=3, force_range=(-1.0, 1.0), cost_range=(-math.inf, 0.8)),
    }
    for name, term in terms.items():
        value = term(state, action)
        assert value.shape == batch_shape, name
        assert value.dtype == dtype, name
        np.testing.assert_allclose(value.double().numpy(), expected[name], rtol=1e-6, atol=1e-6, err_msg=name)


def test_terms_are_differentiable() -> None:
    action = torch.tensor([[0.5, -2.0]], dtype=torch.float64, requires_grad=True)
    ControlCostReward(0.1)(torch.zeros(1, 3, dtype=torch.float64), action).sum().backward()
    torch.testing.assert_close(action.grad, torch.tensor([[-0.1, 0.4]], dtype=torch.float64))

    state = torch.tensor([[3.0, 0.5, -4.0]], dtype=torch.float64, requires_grad=True)
    (
        VelocityReward(2.0, index=0)(state) + ContactCostReward(0.5, start=1, force_range=(-1.0, 1.0))(state)
    ).sum().backward()
    # d/ds0 (2 s0) = 2; d/ds1 -(0.5 s1²) = -s1 = -0.5; s2 is clipped: no gradient
    torch.testing.assert_close(state.grad, torch.tensor([[2.0, -0.5, 0.0]], dtype=torch.float64))


def test_healthy_reward_bounds_finiteness_and_failure() -> None:
    state = torch.tensor([[0.2, 0.0], [1.0, 0.0], [0.5, math.inf], [0.5, math.nan], [0.5, 3.0]])
    strict = HealthyReward(1.0, index=[0, 1], low=[0.2, -math.inf], high=[1.0, math.inf])
    inclusive = HealthyReward(
        1.0, index=[0, 1], low=[0.2, -math.inf], high=[1.0, math.inf], inclusive=True, terminate_when_unhealthy=True
    )
    finite = HealthyReward(
        1.0, index=[0, 1], low=[0.2, -math.inf], high=[1.0, math.inf], inclusive=True, check_finite=True
    )
    assert strict.is_healthy(state).tolist() == [False, False, False, False, True]
    assert inclusive.is_healthy(state).tolist() == [True, True, True, False, True]
    assert finite.is_healthy(state).tolist() == [True, True, False, False, True]
    assert not strict.can_fail and inclusive.can_fail
    assert strict.has_failed(state).tolist() == [False] * 5
    assert inclusive.has_failed(state).tolist() == [False, False, False, True, False]


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: VelocityReward(math.inf), ValueError, "weight"),
        (lambda: VelocityReward(1.0, index=1.5), TypeError, "index"),
        (lambda: ControlCostReward(-0.1), ValueError, "weight"),
        (lambda: ControlCostReward("0.1"), TypeError, "weight"),
        (lambda: HealthyReward(1.0, index=[]), ValueError, "index"),
        (lambda: HealthyReward(1.0, index=[1, 1]), ValueError, "duplicates"),
        (lambda: HealthyReward(1.0, index=[-1]), ValueError, "non-negative"),
        (lambda: HealthyReward(1.0, index="1"), TypeError, "index"),
        (lambda: HealthyReward(1.0, index=[0], low=2.0, high=1.0), ValueError, "low"),
        (lambda: HealthyReward(1.0, index=[0, 1], low=[0.0, 1.0, 2.0]), ValueError, "low"),
        (lambda: HealthyReward(1.0, index=[0], low=math.nan), ValueError, "low"),
        (lambda: HealthyReward(1.0, index=[0], inclusive=1), TypeError, "inclusive"),
        (lambda: HealthyReward(math.nan, index=[0]), ValueError, "healthy_reward"),
        (lambda: ContactCostReward(-1.0), ValueError, "weight"),
        (lambda: ContactCostReward(1.0, start=3, stop=2), ValueError, "start"),
        (lambda: ContactCostReward(1.0, force_range=(1.0, -1.0)), ValueError, "force_range"),
        (lambda: ContactCostReward(1.0, cost_range=5.0), TypeError, "cost_range"),
    ],
)
def test_terms_reject_bad_arguments(make: Any, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        make()


def test_terms_reject_states_that_are_too_small() -> None:
    with pytest.raises(ValueError, match="index"):
        VelocityReward(1.0, index=4)(torch.zeros(2, 3))
    with pytest.raises(ValueError, match="index"):
        HealthyReward(1.0, index=[5])(torch.zeros(2, 3))
    with pytest.raises(ValueError, match="slice"):
        ContactCostReward(1.0, start=3)(torch.zeros(2, 3))
    with pytest.raises(TypeError, match="error_action"):
        ControlCostReward(0.1)(torch.zeros(2, 3), None)


# ----------------------------------------------------------------------------- task construction
def _task_state(env_id: str, unwrapped: Any, x_velocity: float = 0.0) -> torch.Tensor:
    """The task state assembled from MuJoCo data by the test itself, in the documented layout."""
    data = unwrapped.data
    parts = {
        "x_position": np.asarray([data.qpos[0]]),
        "x_velocity": np.asarray([x_velocity]),
        "qpos": data.qpos,
        "qvel": data.qvel,
        "cfrc_ext": data.cfrc_ext.ravel(),
    }
    layout = locomotion_state_layout(env_id)
    return torch.as_tensor(np.concatenate([np.asarray(parts[key], dtype=np.float64) for key in layout]))[None]


def test_supported_env_ids() -> None:
    assert SUPPORTED_ENV_IDS == tuple(ENV_IDS)


@mujoco
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_task_terms_sizes_and_layout(env_id: str) -> None:
    gym_env = gymnasium.make(env_id)
    gym_env.reset(seed=0)
    info = gym_env.step(gym_env.action_space.sample())[-1]
    task = locomotion_task(env_id)
    assert task.term_names == EXPECTED_TERMS[env_id]
    assert set(task.term_names) == {key.removeprefix("reward_") for key in info if key.startswith("reward_")}
    layout = locomotion_state_layout(env_id)
    model = gym_env.unwrapped.model
    sizes = {"x_position": 1, "x_velocity": 1, "qpos": model.nq, "qvel": model.nv, "cfrc_ext": 6 * model.nbody}
    assert layout == {key: sizes[key] for key in layout}
    assert task.state_size == sum(layout.values())
    assert task.action_size == gym_env.action_space.shape[0]
    assert task.reward.can_fail == (env_id in HEALTH_ENVS)
    gym_env.close()


@mujoco
@pytest.mark.parametrize("env_id", HEALTH_ENVS)
def test_terminate_when_unhealthy_false_never_fails(env_id: str) -> None:
    task = locomotion_task(env_id, terminate_when_unhealthy=False)
    assert not task.reward.can_fail
    state = torch.full((2, task.state_size), 1e3, dtype=torch.float64)
    assert task.has_failed(state, task.reset(state)).tolist() == [False, False]


@mujoco
@pytest.mark.parametrize("env_id", HEALTH_ENVS)
def test_health_matches_gymnasium_at_and_around_the_bounds(env_id: str) -> None:
    """The task's health equals Gymnasium's ``is_healthy`` on states at, just inside and just outside every bound."""
    kwargs = {"healthy_state_range": (-10.5, 10.5)} if env_id == "Hopper-v5" else {}
    gym_env = gymnasium.make(env_id, **kwargs)
    gym_env.reset(seed=0)
    unwrapped = gym_env.unwrapped
    survive = locomotion_task(env_id, **kwargs).reward.rewards["survive"]
    qpos0, qvel0 = unwrapped.data.qpos.copy(), unwrapped.data.qvel.copy()
    checked = {
        "Hopper-v5": [("qpos", 1), ("qpos", 2), ("qpos", 3), ("qvel", 0), ("qvel", 4)],
        "Walker2d-v5": [("qpos", 1), ("qpos", 2)],
        "Ant-v5": [("qpos", 2), ("qvel", 3)],
        "Humanoid-v5": [("qpos", 2)],
    }[env_id]
    values = [-11.0, -10.5, -1.0, -0.2, 0.0, 0.2, 0.7, 0.8, 1.0, 1.25, 2.0, 10.2, 10.5, 11.0, math.inf, math.nan]
    values += [np.nextafter(v, math.inf) for v in values[:-2]] + [np.nextafter(v, -math.inf) for v in values[:-2]]
    expected, states = [], []
    for field, index in checked:
        for value in values:
            unwrapped.data.qpos[:] = qpos0
            unwrapped.data.qvel[:] = qvel0
            getattr(unwrapped.data, field)[index] = value
            expected.append(bool(unwrapped.is_healthy))
            states.append(_task_state(env_id, unwrapped))
    healthy = survive.is_healthy(torch.cat(states))
    assert healthy.tolist() == expected
    assert 0 < sum(expected) < len(expected)
    gym_env.close()


@mujoco
def test_hopper_health_reads_the_unclipped_velocities() -> None:
    """The observation clips qvel to ±10; Gymnasium's health check (and the task's) does not."""
    kwargs = {"healthy_state_range": (-10.5, 10.5)}
    env = gymnasium_env("Hopper-v5", seed=0, **kwargs)
    td = env.reset()
    task = env.transform[1].task
    qvel = td["qvel"].clone()
    qvel[3] = 11.0
    state = torch.cat([td["x_velocity"], td["qpos"], qvel])[None]
    assert task.has_failed(state, task.reset(state)).tolist() == [True]
    reference = gymnasium.make("Hopper-v5", **kwargs)
    reference.reset(seed=0)
    reference.unwrapped.set_state(td["qpos"].numpy(), qvel.numpy())
    assert not reference.unwrapped.is_healthy
    assert np.abs(reference.unwrapped._get_obs()).max() <= 10.0  # the observation would look healthy
    reference.close()
    env.close()


@mujoco
@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("Ant-v5", {}),
        ("Ant-v5", {"contact_force_range": (-0.3, 0.2), "contact_cost_weight": 2e-3}),
        ("Humanoid-v5", {}),
        ("Humanoid-v5", {"contact_cost_weight": 3e-5, "contact_cost_range": (-math.inf, 0.7)}),
    ],
)
def test_contact_and_control_costs_match_gymnasium(env_id: str, kwargs: dict[str, Any]) -> None:
    gym_env = gymnasium.make(env_id, **kwargs)
    gym_env.reset(seed=1)
    unwrapped = gym_env.unwrapped
    terms = locomotion_task(env_id, **kwargs).reward.rewards
    rng = np.random.default_rng(1)
    expected_contact, expected_ctrl, states, actions = [], [], [], []
    for _ in range(150):
        action = rng.uniform(gym_env.action_space.low, gym_env.action_space.high).astype(np.float32)
        _, _, terminated, _, _ = gym_env.step(action)
        expected_contact.append(-unwrapped.contact_cost)
        expected_ctrl.append(-unwrapped.control_cost(action))
        states.append(_task_state(env_id, unwrapped))
        actions.append(torch.as_tensor(action, dtype=torch.float64)[None])
        if terminated:
            gym_env.reset()
    state, action = torch.cat(states), torch.cat(actions)
    contact = terms["contact"](state, action).numpy()
    np.testing.assert_allclose(contact, expected_contact, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(terms["ctrl"](state, action).numpy(), expected_ctrl, rtol=1e-6, atol=1e-9)
    assert np.count_nonzero(contact) > 0
    gym_env.close()


@mujoco
@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("frame_skip", [None, 2])
def test_forward_term_is_gymnasiums_weighted_x_velocity(env_id: str, frame_skip: int | None) -> None:
    """forward = forward_reward_weight * info["x_velocity"], the velocity Gymnasium computes with its own dt."""
    kwargs = {"forward_reward_weight": 1.5} if frame_skip is None else {"frame_skip": frame_skip}
    weight = kwargs.get("forward_reward_weight", gymnasium.make(env_id).unwrapped._forward_reward_weight)
    gym_env = gymnasium.make(env_id, **kwargs)
    gym_env.reset(seed=0)
    x_before = float(gym_env.unwrapped.data.qpos[0])
    info = gym_env.step(gym_env.action_space.sample())[-1]
    if env_id not in ("Ant-v5", "Humanoid-v5"):  # their x_velocity is a body's, not qpos[0]'s
        expected_velocity = (float(gym_env.unwrapped.data.qpos[0]) - x_before) / gym_env.unwrapped.dt
        assert info["x_velocity"] == pytest.approx(expected_velocity, rel=1e-12)
    task = locomotion_task(env_id, **kwargs)
    state = _task_state(env_id, gym_env.unwrapped, x_velocity=info["x_velocity"])
    action = torch.zeros(1, task.action_size, dtype=torch.float64)
    terms, _, _ = task.step_reward_terms(state, action, task.reset(state))
    assert terms["forward"].item() == weight * info["x_velocity"] == info["reward_forward"]
    gym_env.close()


# ---------------------------------------------------------------------------------- validation
@mujoco
@pytest.mark.parametrize(
    "build", [locomotion_task, locomotion_state_layout, make_gymnasium_env, gymnasium_env], ids=lambda f: f.__name__
)
def test_unknown_keywords_are_rejected_by_name(build: Any) -> None:
    with pytest.raises(TypeError, match=r"contact_cost_weight.*no_such_option|no_such_option"):
        build("Hopper-v5", contact_cost_weight=1.0, no_such_option=2)
    with pytest.raises(TypeError, match="contact_cost_weight"):
        build("Walker2d-v5", contact_cost_weight=1.0)


@mujoco
@pytest.mark.parametrize(
    ("env_id", "kwargs", "error", "match"),
    [
        ("Hopper-v6", {}, ValueError, "env_id"),
        ("CartPole-v1", {}, ValueError, "env_id"),
        (3, {}, TypeError, "env_id"),
        ("HalfCheetah-v5", {"ctrl_cost_weight": -0.1}, ValueError, "ctrl_cost_weight"),
        ("HalfCheetah-v5", {"forward_reward_weight": math.nan}, ValueError, "forward_reward_weight"),
        ("Ant-v5", {"contact_cost_weight": "5e-4"}, TypeError, "contact_cost_weight"),
        ("Hopper-v5", {"healthy_z_range": (1.0, 0.5)}, ValueError, "healthy_z_range"),
        ("Hopper-v5", {"healthy_state_range": 100.0}, TypeError, "healthy_state_range"),
        ("Walker2d-v5", {"healthy_angle_range": (0.0, math.nan)}, ValueError, "healthy_angle_range"),
        ("Ant-v5", {"contact_force_range": "ab"}, TypeError, "contact_force_range"),
        ("Humanoid-v5", {"contact_cost_range": (1.0, 2.0, 3.0)}, TypeError, "contact_cost_range"),
        ("Humanoid-v5", {"terminate_when_unhealthy": "yes"}, TypeError, "terminate_when_unhealthy"),
        ("Humanoid-v5", {"healthy_reward": math.inf}, ValueError, "healthy_reward"),
        ("Swimmer-v5", {"frame_skip": 0}, ValueError, "frame_skip"),
    ],
)
def test_bad_arguments_are_rejected_by_name(env_id: Any, kwargs: dict[str, Any], error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        locomotion_task(env_id, **kwargs)


@mujoco
def test_gymnasium_env_rejects_bad_num_envs_and_seed() -> None:
    with pytest.raises(ValueError, match="num_envs"):
        gymnasium_env("Swimmer-v5", num_envs=0)
    with pytest.raises(TypeError, match="num_envs"):
        gymnasium_env("Swimmer-v5", num_envs=True)
    with pytest.raises(TypeError, match="seed"):
        gymnasium_env("Swimmer-v5", seed="0")


# ------------------------------------------------------------------------- wrapper and info reader
@mujoco
def test_mujoco_state_info_adds_copies_and_changes_nothing_else() -> None:
    plain = gymnasium.make("Ant-v5")
    wrapped = MujocoStateInfo(gymnasium.make("Ant-v5"), fields=("qpos", "qvel", "cfrc_ext"))
    observation, info = plain.reset(seed=3)
    wrapped_observation, wrapped_info = wrapped.reset(seed=3)
    np.testing.assert_array_equal(observation, wrapped_observation)
    assert set(wrapped_info) == set(info) | {"qpos", "qvel", "cfrc_ext"}
    action = plain.action_space.sample()
    step, wrapped_step = plain.step(action), wrapped.step(action)
    np.testing.assert_array_equal(step[0], wrapped_step[0])
    assert step[1:4] == wrapped_step[1:4]
    data = wrapped.unwrapped.data
    np.testing.assert_array_equal(wrapped_step[4]["qvel"], data.qvel)
    np.testing.assert_array_equal(wrapped_step[4]["cfrc_ext"], data.cfrc_ext.ravel())
    assert wrapped_step[4]["cfrc_ext"].shape == (data.cfrc_ext.size,)
    before = wrapped_step[4]["qpos"].copy()
    wrapped.step(action)
    np.testing.assert_array_equal(wrapped_step[4]["qpos"], before)  # a copy, not a view of MjData
    with pytest.raises(ValueError, match="fields"):
        MujocoStateInfo(gymnasium.make("Ant-v5"), fields=("no_such_array",))
    with pytest.raises(TypeError, match="fields"):
        MujocoStateInfo(gymnasium.make("Ant-v5"), fields="qpos")


def test_float64_info_reader_reshapes_scalars_and_fills_missing_entries() -> None:
    reader = Float64InfoReader({"x_position": 1, "qpos": 3})
    td = reader({"x_position": np.float64(0.25), "qpos": np.array([1, 2, 3])}, TensorDict())
    assert td["x_position"].tolist() == [0.25]
    assert td["qpos"].dtype == torch.float64
    assert td["qpos"].tolist() == [1.0, 2.0, 3.0]
    assert reader({}, TensorDict())["qpos"].tolist() == [0.0, 0.0, 0.0]
    assert reader.info_spec["qpos"].shape == (3,)
    assert reader.info_spec["qpos"].dtype == torch.float64
    with pytest.raises(ValueError, match="the layout size of 'qpos' must be a positive int, got 0"):
        Float64InfoReader({"qpos": 0})
    with pytest.raises(TypeError, match="the layout size of 'qpos' must be a positive int"):
        Float64InfoReader({"qpos": 2.0})
    assert Float64InfoReader({"qpos": np.int64(3)}).layout == {"qpos": 3}
    with pytest.raises(TypeError, match="layout"):
        Float64InfoReader({})


# --------------------------------------------------------------------------------- TorchRL env
@mujoco
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_specs_and_unchanged_observation(env_id: str) -> None:
    env = gymnasium_env(env_id, seed=0)
    check_env_specs(env)
    space = gymnasium.make(env_id).observation_space
    spec = env.observation_spec
    assert spec["observation"].shape == space.shape
    assert spec["observation"].dtype == torch.float64
    layout = locomotion_state_layout(env_id)
    for key, size in layout.items():
        assert spec[key].shape == (size,)
        assert spec[key].dtype == torch.float64
    assert env.transform[1].state_keys == list(layout)
    rollout = env.rollout(3)
    for name in EXPECTED_TERMS[env_id]:
        assert ("next", "task_reward", name) in rollout.keys(True)
    env.close()


@mujoco
def test_device_argument() -> None:
    env = gymnasium_env("Swimmer-v5", seed=0, device="cpu")
    assert env.device == torch.device("cpu")
    assert env.rollout(2)["next", "reward"].device == torch.device("cpu")
    env.close()


@pytest.mark.quick
@mujoco
def test_reward_sum_reports_episode_sums_per_term() -> None:
    env = gymnasium_env("HalfCheetah-v5", seed=0)
    rollout = env.rollout(20)
    nxt = rollout["next"]
    torch.testing.assert_close(nxt["episode_reward"][-1], nxt["reward"].sum(0))
    for name in ("forward", "ctrl"):
        torch.testing.assert_close(nxt["task_reward", f"episode_{name}"][-1], nxt["task_reward", name].sum(0))
    env.close()


@mujoco
@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_parallel_env_with_collector_and_partial_resets() -> None:
    from torchrl.collectors import Collector

    dt = gymnasium.make("Hopper-v5").unwrapped.dt
    env = gymnasium_env("Hopper-v5", num_envs=2, seed=0)
    try:
        check_env_specs(env)
        collector = Collector(env, policy=None, frames_per_batch=200, total_frames=200)
        batch = next(iter(collector))
        collector.shutdown()
    finally:
        if not env.is_closed:
            env.close()
    assert batch.batch_size == (2, 100)
    nxt = batch["next"]
    done = nxt["done"][..., 0]
    # Hopper under random actions falls within a few dozen steps: episodes end at different times
    assert done.sum() >= 4
    assert (done[0] != done[1]).any(), "expected an episode to end in one env while the other continued"
    # every transition's forward term is the finite difference of its own episode's qpos[0]:
    # right after a partial reset the memory holds the new episode's initial x, not the old one's
    forward = nxt["task_reward", "forward"][..., 0]
    expected = (nxt["qpos"][..., 0] - batch["qpos"][..., 0]) / dt
    torch.testing.assert_close(forward, expected.to(forward.dtype), rtol=1e-5, atol=1e-5)
    after_reset = torch.zeros_like(done)
    after_reset[:, 1:] = done[:, :-1]
    assert after_reset.any()
    assert (batch["step_count"][..., 0][after_reset] == 0).all()
    # default Hopper: terminated exactly when unhealthy, and the survive term is 0 exactly then
    terminated = nxt["terminated"][..., 0]
    assert torch.equal(nxt["failure"][..., 0], terminated)
    assert torch.equal(nxt["task_reward", "survive"][..., 0] == 0, terminated)
