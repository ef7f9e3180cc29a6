"""BatchedMujocoEnv: parity with plain Gymnasium, resets, seeding, threads, bad input, specs and the presets.

The parity tests drive ``gymnasium_env(env_id, num_envs=N)`` (a :class:`BatchedMujocoEnv` under
``StepCounter``, the locomotion task's ``TaskTransform`` and ``RewardSum``) and ``N`` independent
``gymnasium.make(env_id, **kwargs)`` envs with :func:`torchtasks.parity.compare_batched_with_gymnasium`
(the lockstep driver behind ``torchtasks check --backend batched``; ``tests/envs/test_batched_parity_check.py``
checks that it reports injected differences). After every reset of a batched env (initial, at the end of
an episode, or forced mid-episode for some envs while the others continue) its ``qpos``/``qvel`` are
copied into the matching Gymnasium env with ``reset()`` + ``unwrapped.set_state`` (which leaves the
MjData as the batched env's reset leaves it), and both get the same actions. Expected values come
from Gymnasium only: the observations must be bit-identical (the two simulations stay in lockstep),
the task reward and each term within 1e-9 of Gymnasium's reward and ``info["reward_*"]``, and
``terminated``/``truncated`` equal.

The actions are drawn in float32 (what TorchRL passes on) and handed to Gymnasium as the same values
in float64: with a float32 action Gymnasium computes its control cost in float32 (NumPy 2 keeps
``weight * np.sum(np.square(action))`` in float32), which differs from the exact value by up to
~1e-7 relative; ``test_float32_actions_only_change_gymnasiums_control_cost_rounding`` measures that.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import warnings
from typing import Any

import numpy as np
import pytest
import torch

from repo_paths import ROOT

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")

from tensordict import TensorDict  # noqa: E402
from torchrl.envs import Compose, ParallelEnv, RewardSum, StepCounter, TransformedEnv  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchtasks.envs import BatchedMujocoEnv, ZeroBrokenStepReward  # noqa: E402
from torchtasks.envs.locomotion import gymnasium_env, locomotion_state_layout, locomotion_task  # noqa: E402
from torchtasks.parity import compare_batched_with_gymnasium  # noqa: E402
from torchtasks.transforms import TaskTransform  # noqa: E402

pytestmark = pytest.mark.mujoco

ENV_IDS = ["HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Swimmer-v5", "Ant-v5", "Humanoid-v5"]
ATOL = 1e-9
NUM_ENVS = 3
STEPS = 200
#: steps after which env 0 (and at the second one env 2 as well) is reset while the others continue
FORCED_RESETS = {60: [0], 130: [0, 2]}

#: keywords that change the dynamics, the observation, the resets or the termination
KEYWORD_CASES: list[tuple[str, dict[str, Any]]] = [
    ("HalfCheetah-v5", {"exclude_current_positions_from_observation": False, "forward_reward_weight": 2.0}),
    ("Hopper-v5", {"frame_skip": 2, "healthy_z_range": (0.8, 2.0), "reset_noise_scale": 0.02}),
    ("Walker2d-v5", {"reset_noise_scale": 0.05, "healthy_angle_range": (-0.5, 0.5), "frame_skip": 3}),
    ("Swimmer-v5", {"exclude_current_positions_from_observation": False, "frame_skip": 2}),
    (
        "Ant-v5",
        {
            "include_cfrc_ext_in_observation": False,
            "healthy_z_range": (0.3, 0.9),
            "contact_force_range": (-0.5, 0.5),
            "main_body": 2,
            "reset_noise_scale": 0.2,
        },
    ),
    ("Ant-v5", {"exclude_current_positions_from_observation": False, "terminate_when_unhealthy": False}),
    (
        "Humanoid-v5",
        {
            "include_cinert_in_observation": False,
            "include_cvel_in_observation": False,
            "healthy_z_range": (0.9, 2.0),
            "exclude_current_positions_from_observation": False,
            "reset_noise_scale": 0.05,
        },
    ),
    ("Humanoid-v5", {"include_qfrc_actuator_in_observation": False, "include_cfrc_ext_in_observation": False}),
]


# ------------------------------------------------------------------------------ parity driver
def _drive(
    env: TransformedEnv,
    env_id: str,
    kwargs: dict[str, Any],
    steps: int,
    *,
    seed: int = 0,
    forced_resets: dict[int, list[int]] | None = None,
    reference_kwargs: dict[str, Any] | None = None,
    float64_reference_actions: bool = True,
) -> dict[str, Any]:
    """Step ``env`` and one Gymnasium env per batch entry in lockstep (``compare_batched_with_gymnasium``).

    The observations must be bit-identical (after every step and every reset), the flags equal and the
    forced partial resets must leave the other envs alone; returns the reward and term differences.
    """
    assert env.base_env.env_id == env_id
    row = compare_batched_with_gymnasium(
        env,
        steps,
        seed=seed,
        forced_resets=forced_resets,
        reference_kwargs={**kwargs, **(reference_kwargs or {})},
        float64_reference_actions=float64_reference_actions,
        tolerance=ATOL,
    )
    context = f"{env_id} {kwargs}: {row['first_mismatch']}"
    differences = row["max_abs_diff"]
    assert differences["observation"] == 0.0, context
    assert differences["terminated"] == differences["truncated"] == differences["done"] == 0.0, context
    assert row["partial_reset_problems"] == 0, context
    result: dict[str, Any] = {"reward": differences["reward"]}
    result.update({f"term_{name}": value for name, value in row["max_abs_term_diff"].items()})
    for key in ("terminated", "truncated", "forced", "episodes"):
        result[key] = row["forced_resets" if key == "forced" else key]
    return result


def _assert_close(result: dict[str, Any]) -> None:
    differences = {key: value for key, value in result.items() if key == "reward" or key.startswith("term_")}
    assert max(differences.values()) <= ATOL, differences


# ------------------------------------------------------------------------------------ parity
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_default_keywords_match_gymnasium_with_partial_resets(env_id: str, record_property: Any) -> None:
    env = gymnasium_env(env_id, num_envs=NUM_ENVS, seed=0)
    assert isinstance(env.base_env, BatchedMujocoEnv)
    result = _drive(env, env_id, {}, STEPS, forced_resets=FORCED_RESETS)
    record_property("max_abs_differences", result)
    _assert_close(result)
    assert result["forced"] == 3
    if env_id in ("Hopper-v5", "Walker2d-v5", "Humanoid-v5"):
        assert result["terminated"] > 0  # episodes end by themselves as well


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    KEYWORD_CASES,
    ids=[f"{env_id}-{'-'.join(kwargs)}" for env_id, kwargs in KEYWORD_CASES],
)
def test_keywords_match_gymnasium(env_id: str, kwargs: dict[str, Any], record_property: Any) -> None:
    env = gymnasium_env(env_id, num_envs=NUM_ENVS, seed=1, **kwargs)
    result = _drive(env, env_id, kwargs, 120, seed=1, forced_resets={50: [1]})
    record_property("max_abs_differences", result)
    _assert_close(result)


def test_truncation_matches_gymnasiums_time_limit() -> None:
    """A hand-built stack (the task path without the preset): StepCounter(40) against max_episode_steps=40."""
    env_id = "HalfCheetah-v5"
    task = locomotion_task(env_id)
    base = BatchedMujocoEnv(env_id, NUM_ENVS, seed=3)
    state_key = list(locomotion_state_layout(env_id))
    env = TransformedEnv(base, Compose(StepCounter(40), TaskTransform(task, state_key=state_key), RewardSum()))
    result = _drive(env, env_id, {}, 130, forced_resets={25: [1], 70: [2]}, reference_kwargs={"max_episode_steps": 40})
    _assert_close(result)
    assert result["truncated"] >= 6  # staggered by the forced resets
    assert result["terminated"] == 0


def test_float32_actions_only_change_gymnasiums_control_cost_rounding() -> None:
    env_id = "Ant-v5"
    result = _drive(gymnasium_env(env_id, num_envs=2, seed=0), env_id, {}, 40, float64_reference_actions=False)
    # the same trajectories (observations are compared bit for bit inside _drive) ...
    assert result["term_forward"] <= ATOL and result["term_contact"] <= ATOL and result["term_survive"] == 0
    # ... and Gymnasium's float32 control cost: float32 rounding of a value of order 1
    assert 1e-9 < result["term_ctrl"] < 1e-6


# ------------------------------------------------------------------------------------ resets
@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("kwargs", [{}, {"reset_noise_scale": 0.3}], ids=["default-noise", "noise-0.3"])
def test_resets_draw_gymnasiums_initial_state_distribution(env_id: str, kwargs: dict[str, Any]) -> None:
    """With each env's generator seeded like Gymnasium's ``reset(seed=s)``, the initial states are identical."""
    env = BatchedMujocoEnv(env_id, 2, **kwargs)
    seeds = [11, 12]
    env.np_random = [np.random.default_rng(seed) for seed in seeds]
    tensordict = env.reset()
    for i, seed in enumerate(seeds):
        reference = gymnasium.make(env_id, **kwargs)
        observation, _ = reference.reset(seed=seed)
        np.testing.assert_array_equal(env.batch.qpos[i], reference.unwrapped.data.qpos)
        np.testing.assert_array_equal(env.batch.qvel[i], reference.unwrapped.data.qvel)
        np.testing.assert_array_equal(tensordict["observation"][i].numpy(), observation)
        reference.close()
    if "x_velocity" in tensordict.keys():
        assert torch.equal(tensordict["x_velocity"], torch.zeros(2, 1, dtype=torch.float64))
    env.close()


def test_seeding_is_reproducible_with_independent_per_env_streams() -> None:
    def initial(seed: int | None, num_envs: int = 4) -> torch.Tensor:
        env = BatchedMujocoEnv("Walker2d-v5", num_envs, seed=seed)
        try:
            return env.reset()["qpos"]
        finally:
            env.close()

    first = initial(5)
    assert torch.equal(first, initial(5))
    assert not torch.equal(first, initial(6))
    assert not torch.equal(initial(None), initial(None))
    assert len({tuple(row.tolist()) for row in first}) == 4  # every env draws its own noise
    env = BatchedMujocoEnv("Walker2d-v5", 4, seed=0)
    env.set_seed(5)
    assert torch.equal(env.reset()["qpos"], first)
    env.close()


def test_partial_reset_touches_only_the_masked_envs() -> None:
    env = BatchedMujocoEnv("Hopper-v5", 4, seed=0)
    tensordict = env.reset()
    for _ in range(5):
        tensordict = env.rand_step(tensordict)["next"]
    batch = env.batch
    states = [(batch.qpos[i].copy(), batch.qvel[i].copy(), batch.time[i]) for i in range(4)]
    mask = torch.tensor([[False], [True], [False], [True]])
    result = env.reset(tensordict.clone().set("_reset", mask))
    for i, (qpos, qvel, time) in enumerate(states):
        if mask[i]:
            assert batch.time[i] == 0.0
            assert not np.array_equal(batch.qpos[i], qpos)
        else:
            assert batch.time[i] == time
            np.testing.assert_array_equal(batch.qpos[i], qpos)
            np.testing.assert_array_equal(batch.qvel[i], qvel)
            assert torch.equal(result["observation"][i], tensordict["observation"][i])
    env.close()


# ----------------------------------------------------------------------------------- threads
@pytest.mark.parametrize("env_id", ["Hopper-v5", "Ant-v5"])
def test_results_do_not_depend_on_the_number_of_threads(env_id: str) -> None:
    rollouts = []
    for num_threads in (1, 2, 3):
        env = BatchedMujocoEnv(env_id, 5, seed=0, num_threads=num_threads)
        assert env.num_threads == num_threads
        torch.manual_seed(0)
        rollouts.append(env.rollout(30, break_when_any_done=False))
        env.close()
    for other in rollouts[1:]:
        for key in ("observation", "qpos", "qvel"):
            assert torch.equal(rollouts[0]["next", key], other["next", key]), key


# --------------------------------------------------------------------------------- bad input
def test_bad_actions_are_rejected_by_name() -> None:
    env = BatchedMujocoEnv("Swimmer-v5", 2, seed=0)
    tensordict = env.reset()
    with pytest.raises(ValueError, match="action"):
        env.step(tensordict.clone().set("action", torch.zeros(2, 3)))
    with pytest.raises(TypeError, match="action"):
        env.step(tensordict.clone().set("action", torch.zeros(2, 2, dtype=torch.int64)))
    with pytest.raises(TypeError, match="action"):
        env.step(tensordict.clone().set("action", torch.zeros(2, 2, dtype=torch.float16)))
    env.close()


def test_a_non_finite_action_ends_only_that_envs_episode() -> None:
    env = BatchedMujocoEnv("Hopper-v5", 3, seed=0)
    tensordict = env.reset()
    qpos = env.batch.qpos[1].copy()
    action = torch.zeros(3, 3)
    action[1, 2] = float("nan")
    with pytest.warns(RuntimeWarning, match=r"non-finite action in envs \[1\], diverged state in envs \[\]"):
        out = env.step(tensordict.set("action", action))["next"]
    assert out["terminated"][:, 0].tolist() == [False, True, False]
    assert out["done"][:, 0].tolist() == [False, True, False]
    np.testing.assert_array_equal(env.batch.qpos[1], qpos)  # not simulated
    assert env.batch.time[0] > 0.0
    env.close()


@pytest.mark.parametrize("steps_before", [0, 3], ids=["right-after-reset", "mid-episode"])
def test_a_diverged_state_ends_the_episode_instead_of_mujocos_silent_reset(steps_before: int) -> None:
    """MuJoCo resets a diverged MjData to qpos0 and carries on; the env ends that episode instead."""
    env = gymnasium_env("Hopper-v5", num_envs=3, seed=0)
    base = env.base_env
    tensordict = env.reset()
    for _ in range(steps_before):
        tensordict = env.step_and_maybe_reset(env.rand_action(tensordict))[1]
    base.batch.qvel[2] = 1e11  # beyond mjMAXVAL: mj_checkVel resets the data
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tensordict, next_root = env.step_and_maybe_reset(env.rand_action(tensordict))
    assert any("diverged state in envs [2]" in str(w.message) for w in caught)
    assert tensordict["next", "terminated"][2].item()
    assert tensordict["next", "done"][2].item()
    assert not tensordict["next", "terminated"][:2].any()
    assert tensordict["next", "broken"][:, 0].tolist() == [False, False, True]
    assert tensordict["next", "reward"][2].item() == 0.0 and tensordict["next", "x_velocity"][2].item() == 0.0
    assert tensordict["next", "episode_reward"].isfinite().all()
    # TorchRL reset env 2: it continues normally from a fresh episode
    assert next_root["step_count"][2].item() == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        tensordict, _ = env.step_and_maybe_reset(env.rand_action(next_root))
    assert not tensordict["next", "done"].any()
    env.close()


def _fixed_actions(num_envs: int, size: int, steps: int) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    return [2 * torch.rand(num_envs, size, generator=generator) - 1 for _ in range(steps)]


def test_a_broken_step_writes_finite_entries_and_marks_the_env() -> None:
    """The env alone: the skipped env repeats its state, moves at 0, pays 0 and is marked "broken"."""
    env = BatchedMujocoEnv("HalfCheetah-v5", 4, seed=0)
    root = env.reset()
    assert not root["broken"].any()
    action = torch.zeros(4, 6)
    action[1, 3] = float("nan")
    with pytest.warns(RuntimeWarning, match="non-finite action in envs \\[1\\]"):
        out = env.step(root.clone().set("action", action))["next"]
    for key in ("broken", "terminated", "done"):
        assert out[key][:, 0].tolist() == [False, True, False, False], key
    assert not out["truncated"].any()
    for key in ("observation", "x_velocity", "reward"):
        assert out[key].isfinite().all(), key
    assert out["reward"][1].item() == 0.0 and out["x_velocity"][1].item() == 0.0
    assert torch.equal(out["observation"][1], root["observation"][1])  # not simulated: the state before the step
    # the next step is not marked, whatever became of env 1
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out = env.step(env.step_mdp(env.step(root.clone().set("action", action.nan_to_num()))))
    assert not out["next", "broken"].any()
    env.close()


def test_a_non_finite_state_is_restarted_like_mujoco_does_and_marked() -> None:
    """A non-finite state that MuJoCo's own checks do not see (here: an env that is not simulated) is not written."""
    env = BatchedMujocoEnv("Hopper-v5", 3, seed=0)
    root = env.reset()
    env.batch.qpos[2] = float("nan")
    action = torch.zeros(3, 3)
    action[2, 0] = float("nan")
    with pytest.warns(RuntimeWarning, match="broken step"):
        out = env.step(root.clone().set("action", action))["next"]
    assert out["broken"][:, 0].tolist() == [False, False, True]
    for key in ("observation", "x_velocity", "qpos", "qvel", "reward"):
        assert out[key].isfinite().all(), key
    np.testing.assert_array_equal(env.batch.qpos[2], env.model.qpos0)
    # its clock restarted with it: the next step is not taken for a diverged one
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out = env.step(env.step_mdp(env.step(root.clone().set("action", torch.zeros(3, 3)))))
    assert not out["next", "broken"].any()
    env.close()


def test_a_broken_step_pays_zero_in_the_preset_and_leaves_the_other_envs_alone() -> None:
    """gymnasium_env with one NaN action: the reward, its terms and the episode sums stay finite.

    Before, the task's control cost of the NaN action was NaN, and RewardSum carried it into
    ``episode_reward`` (and a training batch's statistics). A twin env, stepped with the same actions
    but a finite one for the broken env, gives the other envs' expected values.
    """
    env, twin = (gymnasium_env("HalfCheetah-v5", num_envs=4, seed=0, num_threads=2) for _ in range(2))
    roots = [env.reset(), twin.reset()]
    actions = _fixed_actions(4, 6, 6)
    broken_at = 3
    for t, action in enumerate(actions):
        twin_action = action
        if t == broken_at:
            action = action.clone()
            action[1, 2] = float("nan")
            before = roots[0].clone()  # the episode sums before the broken step
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            (out, root), (twin_out, twin_root) = (
                e.step_and_maybe_reset(r.set("action", a))
                for e, r, a in ((env, roots[0], action), (twin, roots[1], twin_action))
            )
        nxt, twin_nxt = out["next"], twin_out["next"]
        reward_keys = ["reward", "episode_reward", *(("task_reward", k) for k in nxt["task_reward"].keys())]
        for key in reward_keys:
            assert nxt[key].isfinite().all(), (t, key)
        if t != broken_at:
            assert not caught and not nxt["broken"].any()
            for key in (*reward_keys, "observation", "done"):
                if t < broken_at:
                    assert torch.equal(nxt[key], twin_nxt[key]), (t, key)
        else:
            assert len(caught) == 1 and "non-finite action in envs [1]" in str(caught[0].message)
            others = [0, 2, 3]
            for key in ("broken", "terminated", "done"):
                assert nxt[key][:, 0].tolist() == [False, True, False, False], key
            assert not nxt["failure"].any()
            for key in reward_keys:
                is_sum = (key if isinstance(key, str) else key[-1]).startswith("episode_")
                expected = before[key][1] if is_sum else torch.zeros_like(nxt[key][1])
                assert torch.equal(nxt[key][1], expected), key
                assert torch.equal(nxt[key][others], twin_nxt[key][others]), key  # the others are unaffected
            assert torch.equal(nxt["observation"][others], twin_nxt["observation"][others])
            assert root["step_count"][:, 0].tolist() == [t + 1, 0, t + 1, t + 1]  # only env 1 starts again
            assert not root["broken"].any()
        roots = [root, twin_root]
    env.close()
    twin.close()


def test_zero_broken_step_reward_needs_the_marker() -> None:
    from torchtasks.envs import PendulumEnv

    env = TransformedEnv(PendulumEnv(batch_size=[2]), ZeroBrokenStepReward())
    with pytest.raises(KeyError, match="broken"):
        env.observation_spec  # noqa: B018
    with pytest.raises(TypeError, match="broken_key"):
        ZeroBrokenStepReward(broken_key=("next", "broken"))


@pytest.mark.parametrize(
    ("value", "error", "message"),
    [
        (-1, ValueError, "reset_noise_scale must be non-negative, got -1"),
        (math.nan, ValueError, "reset_noise_scale must be finite, got nan"),
        (math.inf, ValueError, "reset_noise_scale must be finite, got inf"),
        ("0.1", TypeError, "reset_noise_scale must be a real number, got '0.1'"),
        (None, TypeError, "reset_noise_scale must be a real number, got None"),
    ],
)
def test_reset_noise_scale_is_checked_at_construction(value: Any, error: type[Exception], message: str) -> None:
    """Before, -1 and NaN were accepted and '0.1' failed at the first reset with numpy's message."""
    builders = {
        "BatchedMujocoEnv": lambda: BatchedMujocoEnv("Hopper-v5", 2, reset_noise_scale=value),
        "gymnasium_env batched": lambda: gymnasium_env("Hopper-v5", num_envs=2, reset_noise_scale=value),
        "gymnasium_env gymnasium": lambda: gymnasium_env("Hopper-v5", reset_noise_scale=value),
        "locomotion_task": lambda: locomotion_task("Hopper-v5", reset_noise_scale=value),
    }
    for name, build in builders.items():
        with pytest.raises(error) as caught:
            build()
        assert message in str(caught.value), name


def test_reset_noise_scale_accepts_zero_and_numpy_numbers() -> None:
    env = BatchedMujocoEnv("Hopper-v5", 2, seed=0, reset_noise_scale=np.float64(0.0))
    qpos = env.reset()["qpos"]
    torch.testing.assert_close(qpos, torch.as_tensor(env.init_qpos).expand(2, -1), rtol=0, atol=0)
    env.close()


def test_numpy_integers_are_accepted_as_num_envs_everywhere() -> None:
    """Before, gymnasium_env rejected num_envs=np.int64(2) while BatchedMujocoEnv accepted it."""
    env = BatchedMujocoEnv("Swimmer-v5", np.int64(2), num_threads=np.int32(1))
    assert env.batch_size == (2,) and type(env.num_envs) is int and type(env.num_threads) is int
    env.close()
    preset = gymnasium_env("Swimmer-v5", num_envs=np.int64(2), frame_skip=np.int64(2), num_threads=1)
    assert preset.batch_size == (2,) and preset.base_env.frame_skip == 2
    preset.close()
    parallel = gymnasium_env("Swimmer-v5", num_envs=np.int64(2), backend="gymnasium")
    assert parallel.batch_size == (2,)  # not started: no worker is spawned here
    with pytest.raises(TypeError, match=r"num_envs must be a positive int, got 2\.0"):
        gymnasium_env("Swimmer-v5", num_envs=2.0)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"num_envs": 0}, ValueError, "num_envs"),
        ({"num_envs": True}, TypeError, "num_envs"),
        ({"num_envs": 2.0}, TypeError, "num_envs"),
        ({"num_threads": 0}, ValueError, "num_threads"),
        ({"num_threads": np.float64(2)}, TypeError, "num_threads"),
        ({"frame_skip": True}, TypeError, "frame_skip"),
        ({"seed": "0"}, TypeError, "seed"),
        ({"render_mode": "rgb_array"}, ValueError, "render"),
        ({"no_such_keyword": 1}, TypeError, "no_such_keyword"),
        ({"healthy_z_range": (1.0, 0.5)}, ValueError, "healthy_z_range"),
    ],
)
def test_bad_arguments_are_rejected_by_name(kwargs: dict[str, Any], error: type[Exception], match: str) -> None:
    kwargs = {"num_envs": 2, **kwargs}
    with pytest.raises(error, match=match):
        BatchedMujocoEnv("Hopper-v5", **kwargs)


def test_unknown_env_ids_are_rejected() -> None:
    # neither a preset nor a model: the message names the presets, the closest one, and the way to a model of one's own
    with pytest.raises(ValueError, match=r"neither a Gymnasium preset .*'Hopper-v5'.*Your own robot"):
        BatchedMujocoEnv("CartPole-v1", 2)
    with pytest.raises(ValueError, match=r"did you mean 'Hopper-v5'\?"):
        BatchedMujocoEnv("Hoper-v5", 2)


# ------------------------------------------------------------------------------------- specs
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_specs(env_id: str) -> None:
    env = BatchedMujocoEnv(env_id, 2, seed=0)
    check_env_specs(env)
    reference = gymnasium.make(env_id)
    assert env.batch_size == (2,)
    assert env.observation_spec["observation"].shape == (2, *reference.observation_space.shape)
    assert env.observation_spec["observation"].dtype == torch.float64
    layout = locomotion_state_layout(env_id)
    assert set(env.observation_spec.keys()) == {"observation", "broken", *layout}
    assert env.observation_spec["broken"].dtype == torch.bool and env.observation_spec["broken"].shape == (2, 1)
    for key, size in layout.items():
        assert env.observation_spec[key].shape == (2, size)
        assert env.observation_spec[key].dtype == torch.float64
    action = env.action_spec
    assert action.dtype == torch.float32
    np.testing.assert_array_equal(action.space.low[0].numpy(), reference.action_space.low)
    np.testing.assert_array_equal(action.space.high[0].numpy(), reference.action_space.high)
    assert env.reward_spec.dtype == torch.float64
    assert set(env.full_done_spec.keys()) == {"done", "terminated", "truncated"}
    reference.close()
    env.close()


def test_device_argument() -> None:
    env = BatchedMujocoEnv("Swimmer-v5", 2, seed=0, device="cpu")
    assert env.device == torch.device("cpu")
    assert env.rollout(2)["next", "observation"].device == torch.device("cpu")
    env.close()


def test_the_env_pays_no_reward_and_ends_no_episode_by_itself() -> None:
    env = BatchedMujocoEnv("Hopper-v5", 2, seed=0)
    rollout = env.rollout(60, break_when_any_done=False)  # Hopper falls under random actions
    assert not rollout["next", "done"].any()
    assert torch.equal(rollout["next", "reward"], torch.zeros(2, 60, 1, dtype=torch.float64))
    env.close()


def test_outputs_are_fresh_tensors_at_every_step() -> None:
    """Returned steps keep their values: nothing the env returns is a view of a buffer it writes again."""
    env = BatchedMujocoEnv("Ant-v5", 2, seed=0)
    tensordict = env.reset()
    kept, copies = [tensordict], [tensordict.clone()]
    for _ in range(30):
        tensordict = env.rand_step(tensordict)["next"]
        kept.append(tensordict)
        copies.append(tensordict.clone())
    keys = ["observation", "qpos", "qvel", "cfrc_ext", "x_velocity"]
    for stored, copy in zip(kept, copies, strict=True):
        for key in keys:
            assert torch.equal(stored[key], copy[key]), key
    assert any(stored["cfrc_ext"].abs().sum() > 0 for stored in kept)  # contact forces were gathered
    env.close()


# ----------------------------------------------------------------------------------- presets
def test_gymnasium_env_selects_the_backend() -> None:
    env = gymnasium_env("Hopper-v5", num_envs=2, seed=0, num_threads=1)
    assert isinstance(env.base_env, BatchedMujocoEnv)
    assert env.base_env.num_threads == 1
    assert env.output_spec["full_reward_spec", "reward"].dtype == torch.float64
    env.close()
    single = gymnasium_env("Hopper-v5", backend="batched")
    assert isinstance(single.base_env, BatchedMujocoEnv) and single.batch_size == (1,)
    single.close()
    parallel = gymnasium_env("Hopper-v5", num_envs=2, backend="gymnasium")
    assert isinstance(parallel.base_env, ParallelEnv)  # not started: no worker is spawned here
    with pytest.raises(ValueError, match="backend"):
        gymnasium_env("Hopper-v5", num_envs=2, backend="envpool")
    with pytest.raises(ValueError, match="num_threads"):
        gymnasium_env("Hopper-v5", num_envs=2, backend="gymnasium", num_threads=2)


def test_collector_over_the_batched_preset() -> None:
    from torchrl.collectors import Collector

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    env = gymnasium_env("Hopper-v5", num_envs=4, seed=0)
    dt = env.base_env.dt
    collector = Collector(env, policy=None, frames_per_batch=400, total_frames=400)
    try:
        batch = next(iter(collector))
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    assert batch.batch_size == (4, 100)
    nxt = batch["next"]
    done = nxt["done"][..., 0]
    assert done.sum() >= 4 and (done.any(1)).all()
    # each forward term is its own episode's finite difference, also right after partial resets
    expected = (nxt["qpos"][..., 0] - batch["qpos"][..., 0]) / dt
    torch.testing.assert_close(nxt["task_reward", "forward"][..., 0], expected, rtol=0, atol=1e-9)
    after_reset = torch.zeros_like(done)
    after_reset[:, 1:] = done[:, :-1]
    assert (batch["step_count"][..., 0][after_reset] == 0).all()
    assert not batch["next", "broken"].any()  # the marker is collected (and no step was broken)
    assert torch.equal(nxt["failure"][..., 0], nxt["terminated"][..., 0])


def test_importing_torchtasks_envs_does_not_import_the_batched_env_or_gymnasium() -> None:
    code = (
        "import sys, torchtasks, torchtasks.envs\n"
        "assert 'gymnasium' not in sys.modules\n"
        "assert 'torchtasks.envs.batched_mujoco' not in sys.modules\n"
        "assert torchtasks.envs.BatchedMujocoEnv.__module__ == 'torchtasks.envs.batched_mujoco'\n"
        "assert 'BatchedMujocoEnv' in torchtasks.envs.__all__\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


def test_reset_output_of_a_fresh_env_has_every_entry() -> None:
    env = BatchedMujocoEnv("Humanoid-v5", 2, seed=0)
    td = env.reset()
    assert isinstance(td, TensorDict)
    assert set(td.keys()) >= {"observation", "x_velocity", "qpos", "cfrc_ext", "done", "terminated", "truncated"}
    assert not td["done"].any()
    env.close()


@pytest.mark.multiprocess  # the ParallelEnv preset starts worker processes
@pytest.mark.xdist_group("multiprocess")
def test_benchmark_script_runs_every_measurement(tmp_path: Any, fork_start_method) -> None:
    """``benchmarks/batched_mujoco.py --tiny``: every code path with tiny sizes (timings mean nothing).

    The preset's workers are forked here (TorchRL takes the global start method): spawned, as a user's run starts
    them, each would import torch anew (8 s of the test's 9 s on an idle machine) for no code path of its own.

    envpool (and gym, treevalue) live in the benchmark venv only: here their columns say "not installed".
    """
    import importlib.util
    import json

    path = ROOT / "benchmarks" / "batched_mujoco.py"
    spec = importlib.util.spec_from_file_location("batched_mujoco_benchmark", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    threads = torch.get_num_threads()
    assert module.main(["--tiny", "--output", str(tmp_path)]) == 0
    assert torch.get_num_threads() == threads
    results = json.loads((tmp_path / "results.json").read_text())
    rows = results["rows"]
    assert [(row["env"], row["num_envs"]) for row in rows] == [("Hopper-v5", 2), ("Ant-v5", 3)]
    for row in rows:
        assert all(row[f"{variant}_median"] > 0 for variant in module.VARIANTS)
        assert row["floor_median"] >= row["floor_threads_median"]
        assert row["gym_vector_median"] > 0
        for peer in module.PEERS:
            missing = module.peer_status(peer)
            assert (row[f"{peer}_median"] is None) == (missing is not None)
            assert row["peer_status"][peer] == missing
    # --tiny measures the preset for the first env id only
    assert results["presets"]["Hopper-v5"]["frames_per_second"] > 0
    assert rows[0]["collector_over_preset"] > 0
    assert rows[1]["preset_median"] is None
    table = (tmp_path / "results.md").read_text()
    assert table.count("| Hopper-v5 | 2 |") == 1
    assert re.search(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC, 1-minute load average [\d.]+ before, [\d.]+ after", table)
    assert f"`python benchmarks/batched_mujoco.py --tiny --output {tmp_path}`" in table, table
    if module.peer_status("envpool_raw") is not None:
        assert "not installed (envpool)" in table


def test_pipeline_costs_script_runs(tmp_path: Any) -> None:
    """``benchmarks/pipeline_costs.py`` on a tiny case: every variant measured, the table written."""
    import importlib.util
    import json
    import sys

    folder = ROOT / "benchmarks"
    sys.path.insert(0, str(folder))  # the script imports its helpers from batched_mujoco.py beside it
    try:
        spec = importlib.util.spec_from_file_location("pipeline_costs_benchmark", folder / "pipeline_costs.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(folder))
    threads = torch.get_num_threads()
    arguments = ["--cases", "Hopper-v5:2", "--repeats", "1", "--steps", "3", "--threads", "1"]
    assert module.main([*arguments, "--output", str(tmp_path)]) == 0
    assert torch.get_num_threads() == threads
    (row,) = json.loads((tmp_path / "results.json").read_text())["rows"]
    assert row["env_id"] == "Hopper-v5" and row["num_envs"] == 2
    assert set(row["frames_per_second"]) == set(module.VARIANTS)
    assert all(value > 0 for value in row["frames_per_second"].values())
    table = (tmp_path / "results.md").read_text()
    assert "| Hopper-v5 × 2 |" in table
    # the table says when, under which load and with which command it was measured (the docs include it as is)
    command = "python benchmarks/pipeline_costs.py " + " ".join([*arguments, "--output", str(tmp_path)])
    assert re.search(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC, 1-minute load average [\d.]+ before, [\d.]+ after", table), table
    assert f"`{command}`" in table, table
