"""Parity of the Gymnasium MuJoCo v5 locomotion presets with plain Gymnasium.

Each test drives ``gymnasium_env(env_id, seed=seed, **kwargs)`` (TorchRL, task reward) and an
independent ``gymnasium.make(env_id, **kwargs)`` with the same seed and the same explicit actions,
resets both whenever Gymnasium ends an episode (terminated, or truncated at 1000 steps), and
compares every step: the task reward with Gymnasium's reward (1e-5 absolute; TorchRL's reward spec
is float32), each logged term ``("task_reward", name)`` with ``info["reward_<name>"]``,
``terminated``/``truncated`` and the task's ``failure`` with Gymnasium's flags, and the observations
(bit-identical, which shows that the two envs stay synchronised). Expected values come from
Gymnasium only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")
torch = pytest.importorskip("torch")

from torchtasks.envs.locomotion import gymnasium_env  # noqa: E402
from torchtasks.parity import check_parity, format_parity_table  # noqa: E402

pytestmark = pytest.mark.mujoco

ENV_IDS = ["HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Swimmer-v5", "Ant-v5", "Humanoid-v5"]
#: one seed per env (a seed draws another start and other random actions: the same comparison), seeds 0, 1 and 2
#: each twice; 1000 steps reach the time limit of the envs that never terminate
SEEDS = dict(zip(ENV_IDS, [0, 1, 2, 1, 2, 0], strict=True))
STEPS = 1000
ATOL = 1e-5

#: keyword arguments that change Gymnasium's reward or termination (one seed, shorter runs)
KEYWORD_CASES: list[tuple[str, dict[str, Any]]] = [
    (
        "HalfCheetah-v5",
        {"forward_reward_weight": 2.0, "ctrl_cost_weight": 0.5, "exclude_current_positions_from_observation": False},
    ),
    ("Hopper-v5", {"healthy_z_range": (0.3, 0.9)}),
    (
        "Hopper-v5",
        {
            "healthy_state_range": (-5.0, 5.0),
            "healthy_angle_range": (-0.3, 0.3),
            "healthy_reward": 3.0,
            "terminate_when_unhealthy": False,
        },
    ),
    (
        "Walker2d-v5",
        {
            "healthy_z_range": (0.9, 2.0),
            "healthy_angle_range": (-0.5, 0.5),
            "healthy_reward": 2.0,
            "ctrl_cost_weight": 0.01,
        },
    ),
    ("Swimmer-v5", {"forward_reward_weight": 0.5, "ctrl_cost_weight": 0.5, "frame_skip": 2}),
    (
        "Ant-v5",
        {
            "healthy_z_range": (0.3, 0.9),
            "contact_force_range": (-0.5, 0.5),
            "contact_cost_weight": 1e-3,
            "ctrl_cost_weight": 0.25,
            "main_body": 2,
        },
    ),
    ("Ant-v5", {"terminate_when_unhealthy": False, "include_cfrc_ext_in_observation": False}),
    (
        "Humanoid-v5",
        {
            "contact_cost_weight": 2e-5,
            "contact_cost_range": (-math.inf, 1.0),
            "healthy_z_range": (0.9, 2.0),
            "ctrl_cost_weight": 0.2,
            "forward_reward_weight": 1.0,
        },
    ),
]
KEYWORD_STEPS = 300


def _actions(reference: Any, seed: int, steps: int) -> np.ndarray:
    """The random actions of a run: uniform in the action box, float32 (what TorchRL passes on)."""
    rng = np.random.default_rng(seed)
    space = reference.action_space
    return rng.uniform(space.low, space.high, size=(steps, *space.shape)).astype(space.dtype)


def _run_gymnasium(env_id: str, seed: int, actions: np.ndarray, kwargs: dict[str, Any]) -> dict[str, Any]:
    """Plain Gymnasium: ``reset(seed=seed)``, ``reset()``, then ``actions``, resetting when an episode ends."""
    env = gymnasium.make(env_id, **kwargs)
    try:
        env.reset(seed=seed)
        observation, _ = env.reset()
        out: dict[str, Any] = {"observation0": observation, "observation": [], "reward": [], "info": []}
        out["terminated"], out["truncated"] = [], []
        for action in actions:
            observation, reward, terminated, truncated, info = env.step(action)
            out["observation"].append(observation)
            out["reward"].append(float(reward))
            out["terminated"].append(bool(terminated))
            out["truncated"].append(bool(truncated))
            out["info"].append({key: float(value) for key, value in info.items() if key.startswith("reward_")})
            if terminated or truncated:
                env.reset()
        return out
    finally:
        env.close()


def _run_preset(env_id: str, seed: int, actions: np.ndarray, kwargs: dict[str, Any]) -> dict[str, Any]:
    """The preset, driven step by step with explicit actions; TorchRL resets it when it is done."""
    env = gymnasium_env(env_id, seed=seed, **kwargs)
    try:
        names = env.transform[1].task.term_names
        tensordict = env.reset()
        out: dict[str, Any] = {"names": names, "observation0": tensordict["observation"].numpy().copy()}
        columns: dict[str, list[Any]] = {
            key: [] for key in ("observation", "reward", "terminated", "truncated", "done", "failure")
        }
        terms: dict[str, list[float]] = {name: [] for name in names}
        for action in actions:
            tensordict["action"] = torch.from_numpy(action)
            tensordict, next_root = env.step_and_maybe_reset(tensordict)
            result = tensordict["next"]
            columns["observation"].append(result["observation"].numpy().copy())
            columns["reward"].append(result["reward"].item())
            for key in ("terminated", "truncated", "done", "failure"):
                columns[key].append(result[key].item())
            for name in names:
                terms[name].append(result["task_reward", name].item())
            tensordict = next_root
        out.update(columns)
        out["terms"] = terms
        return out
    finally:
        env.close()


def _compare(env_id: str, seed: int, steps: int, kwargs: dict[str, Any]) -> dict[str, Any]:
    reference = gymnasium.make(env_id, **kwargs)
    actions = _actions(reference, seed, steps)
    reference.close()
    expected = _run_gymnasium(env_id, seed, actions, kwargs)
    got = _run_preset(env_id, seed, actions, kwargs)

    np.testing.assert_array_equal(got["observation0"], expected["observation0"], err_msg="initial observations differ")
    # the terms are exactly those Gymnasium logs
    logged = {key.removeprefix("reward_") for key in expected["info"][0]}
    assert set(got["names"]) == logged
    for step in range(steps):
        context = f"{env_id} {kwargs} seed {seed} step {step}"
        assert got["terminated"][step] == expected["terminated"][step], f"terminated differs at {context}"
        assert got["failure"][step] == (expected["terminated"][step]), f"task failure differs at {context}"
        assert got["truncated"][step] == expected["truncated"][step], f"truncated differs at {context}"
        np.testing.assert_array_equal(
            got["observation"][step], expected["observation"][step], err_msg=f"observations differ at {context}"
        )
    reward_error = np.abs(np.asarray(got["reward"]) - np.asarray(expected["reward"]))
    assert reward_error.max() <= ATOL, f"reward differs by {reward_error.max():.3g} at step {reward_error.argmax()}"
    for name in got["names"]:
        gym_term = np.asarray([info[f"reward_{name}"] for info in expected["info"]])
        term_error = np.abs(np.asarray(got["terms"][name]) - gym_term)
        assert term_error.max() <= ATOL, (
            f"term {name!r} differs by {term_error.max():.3g} at step {term_error.argmax()}"
        )
    return {"expected": expected, "got": got, "actions": actions}


@pytest.mark.parametrize(("env_id", "seed"), SEEDS.items(), ids=[f"{env_id}-{seed}" for env_id, seed in SEEDS.items()])
def test_reward_terms_and_termination_match_gymnasium(env_id: str, seed: int) -> None:
    result = _compare(env_id, seed, STEPS, {})
    if env_id in ("Hopper-v5", "Walker2d-v5", "Ant-v5", "Humanoid-v5"):
        # random actions end episodes early in the envs that terminate: resets are exercised
        assert any(result["expected"]["terminated"])


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    KEYWORD_CASES,
    ids=[f"{env_id}-{'-'.join(kwargs)}" for env_id, kwargs in KEYWORD_CASES],
)
def test_keyword_arguments_change_gymnasium_and_the_preset_identically(env_id: str, kwargs: dict[str, Any]) -> None:
    result = _compare(env_id, 0, KEYWORD_STEPS, kwargs)
    # the keywords matter: Gymnasium with its defaults pays different rewards for the same actions
    defaults = _run_gymnasium(env_id, 0, result["actions"], {})
    assert not np.allclose(result["expected"]["reward"], defaults["reward"], atol=1e-3)


def test_check_parity_reports_a_matching_preset() -> None:
    row = check_parity("Walker2d-v5", seeds=[4], steps=120, healthy_reward=2.0)
    assert row["env"] == "Walker2d-v5"
    assert row["kwargs"] == {"healthy_reward": 2.0}
    assert row["seeds"] == [4]
    assert row["steps"] == 120
    assert row["episodes"] >= 1
    assert set(row["max_abs_term_diff"]) == {"forward", "ctrl", "survive"}
    assert row["max_abs_reward_diff"] <= ATOL
    assert max(row["max_abs_term_diff"].values()) <= ATOL
    assert row["termination_mismatches"] == 0
    assert row["observation_mismatches"] == 0
    table = format_parity_table([row])
    lines = table.splitlines()
    assert len(lines) == 3
    assert lines[0].startswith("| env |")
    assert lines[2].startswith("| Walker2d-v5 (healthy_reward=2.0) | 4 | 120 |")
    assert lines[2].count("|") == lines[0].count("|")


def test_check_parity_detects_a_preset_that_differs(monkeypatch: pytest.MonkeyPatch) -> None:
    import torchtasks.parity as parity

    def mismatched_env(env_id: str, **kwargs: Any) -> Any:
        return gymnasium_env(env_id, **kwargs, ctrl_cost_weight=0.5)

    monkeypatch.setattr(parity, "gymnasium_env", mismatched_env)
    row = parity.check_parity("HalfCheetah-v5", seeds=[0], steps=20)
    assert row["max_abs_term_diff"]["ctrl"] > 1e-2
    assert row["max_abs_reward_diff"] > 1e-2
    assert row["max_abs_term_diff"]["forward"] <= ATOL


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"seeds": []}, ValueError, "seeds"),
        ({"seeds": 3}, TypeError, "seeds"),
        ({"seeds": [-1]}, ValueError, "seeds"),
        ({"steps": 0}, ValueError, "steps"),
        ({"no_such_keyword": 1}, TypeError, "no_such_keyword"),
    ],
)
def test_check_parity_rejects_bad_arguments(kwargs: dict[str, Any], error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        check_parity("Swimmer-v5", **kwargs)


def test_format_parity_table_rejects_bad_rows() -> None:
    with pytest.raises(TypeError, match="rows"):
        format_parity_table([1])
    with pytest.raises(ValueError, match="max_abs_reward_diff"):
        format_parity_table([{"env": "Hopper-v5", "seeds": [0], "steps": 1, "max_abs_term_diff": {}}])
