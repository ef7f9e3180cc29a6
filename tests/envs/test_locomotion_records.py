"""The records of ``torchtasks.envs.gymnasium_v5``: each record's facts agree with a made Gymnasium env, and
the builders make one Gymnasium env and check the keywords once.

Expected values come from Gymnasium alone: its observation (rebuilt from the record's parts on the
env's own ``MjData``), its ``info["reward_*"]`` keys, its ``info["x_velocity"]`` (the finite
difference of the record's forward position) and its reset draws (the record's noise kind on the
same seeded generator).
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")

import torchtasks.envs.batched_mujoco as batched_mujoco  # noqa: E402
import torchtasks.envs.locomotion as locomotion  # noqa: E402
from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs.gymnasium_v5 import (  # noqa: E402
    LOCOMOTION_ENVS,
    LocomotionEnvRecord,
    ModelFacts,
    gymnasium_config,
    locomotion_record,
)

pytestmark = pytest.mark.mujoco

ENV_IDS = list(LOCOMOTION_ENVS)

#: keyword sets that change the observation (every record's default, plus the flags each env has)
OBSERVATION_CASES: list[tuple[str, dict[str, Any]]] = [
    *((env_id, {}) for env_id in ENV_IDS),
    *((env_id, {"exclude_current_positions_from_observation": False}) for env_id in ENV_IDS),
    ("Ant-v5", {"include_cfrc_ext_in_observation": False}),
    ("Ant-v5", {"contact_force_range": (-0.5, 0.5)}),
    ("Humanoid-v5", {"include_cinert_in_observation": False, "include_cvel_in_observation": False}),
    ("Humanoid-v5", {"include_qfrc_actuator_in_observation": False, "include_cfrc_ext_in_observation": False}),
]


def _stepped(env_id: str, kwargs: dict[str, Any], steps: int = 5) -> tuple[Any, np.ndarray, dict[str, Any]]:
    """A made Gymnasium env after a seeded reset and ``steps`` seeded random actions, its observation and info."""
    env = gymnasium.make(env_id, disable_env_checker=True, **kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(steps):
        observation, _, _, _, info = env.step(env.action_space.sample())
    return env, observation, info


def _forward_position(record: LocomotionEnvRecord, env: Any, config: dict[str, Any]) -> float:
    """The x coordinate that the record says Gymnasium finite-differences into ``x_velocity``."""
    data, model = env.unwrapped.data, env.unwrapped.model
    if record.forward_position == "qpos":
        return float(data.qpos[0])
    if record.forward_position == "main_body":
        return float(data.xpos[model.body(config["main_body"]).id, 0])
    assert record.forward_position == "mass_centre"
    return float(np.sum(model.body_mass[:, None] * data.xipos, axis=0)[0] / np.sum(model.body_mass))


def test_the_table_is_the_supported_ids_and_read_only() -> None:
    assert tuple(LOCOMOTION_ENVS) == locomotion.SUPPORTED_ENV_IDS
    for env_id, record in LOCOMOTION_ENVS.items():
        assert record.env_id == env_id and locomotion_record(env_id) is record
    with pytest.raises(TypeError):
        LOCOMOTION_ENVS["Reacher-v5"] = LOCOMOTION_ENVS["Hopper-v5"]  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        LOCOMOTION_ENVS["Hopper-v5"].velocity_clip = None  # type: ignore[misc]
    with pytest.raises(ValueError, match=r"env_id must be one of \['HalfCheetah-v5'"):
        locomotion_record("Reacher-v5")
    with pytest.raises(TypeError, match="env_id must be a string"):
        locomotion_record(5)


@pytest.mark.parametrize(("env_id", "kwargs"), OBSERVATION_CASES, ids=lambda v: v if isinstance(v, str) else str(v))
def test_the_observation_parts_rebuild_gymnasiums_observation(env_id: str, kwargs: dict[str, Any]) -> None:
    """Skipped positions, velocity clip and extra parts: Gymnasium's observation, bit for bit, from its own MjData."""
    record = locomotion_record(env_id)
    config = gymnasium_config(env_id, kwargs)
    env, observation, _ = _stepped(env_id, kwargs)
    data = env.unwrapped.data
    pieces = []
    for part in record.observation_parts(config):
        piece = np.array(getattr(data, part.source))[part.start :].ravel()
        pieces.append(piece if part.clip is None else np.clip(piece, *part.clip))
    np.testing.assert_array_equal(np.concatenate(pieces), observation)
    assert ModelFacts.of(env).observation_size == observation.size
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_terms_state_and_forward_position_agree_with_gymnasium(env_id: str) -> None:
    record = locomotion_record(env_id)
    config = gymnasium_config(env_id, {})
    env, _, info = _stepped(env_id, {}, steps=3)
    assert set(record.term_names) == {key.removeprefix("reward_") for key in info if key.startswith("reward_")}
    facts = ModelFacts.of(env)
    layout = record.state_layout(facts)
    data = env.unwrapped.data
    assert list(layout) == list(record.state_keys) and layout["x_velocity"] == 1
    for key in record.state_keys[1:]:  # the MjData arrays the task reads
        assert layout[key] == getattr(data, key).size, key
    # x_velocity is the finite difference of the record's forward position over one step
    before = _forward_position(record, env, config)
    _, _, _, _, info = env.step(env.action_space.sample())
    after = _forward_position(record, env, config)
    assert info["x_velocity"] == pytest.approx((after - before) / facts.dt, rel=1e-12, abs=1e-12)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_velocity_noise_kind_is_gymnasiums(env_id: str) -> None:
    """Gymnasium's reset, replayed on the same seeded generator with the record's noise kind."""
    record = locomotion_record(env_id)
    scale = 0.3
    env = gymnasium.make(env_id, disable_env_checker=True, reset_noise_scale=scale)
    env.reset(seed=7)
    unwrapped = env.unwrapped
    rng, _ = gymnasium.utils.seeding.np_random(7)
    qpos = unwrapped.init_qpos + rng.uniform(low=-scale, high=scale, size=unwrapped.model.nq)
    if record.velocity_noise == "normal":
        qvel = unwrapped.init_qvel + scale * rng.standard_normal(unwrapped.model.nv)
    else:
        assert record.velocity_noise == "uniform"
        qvel = unwrapped.init_qvel + rng.uniform(low=-scale, high=scale, size=unwrapped.model.nv)
    np.testing.assert_array_equal(unwrapped.data.qpos, qpos)
    np.testing.assert_array_equal(unwrapped.data.qvel, qvel)
    env.close()


# ------------------------------------------------------------------- one make, one check
def _count(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Count ``gymnasium.make`` calls and keyword checks (``gymnasium_config`` wherever it is read from)."""
    counts = {"make": 0, "config": 0}

    def counted(name: str, function: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            counts[name] += 1
            return function(*args, **kwargs)

        return wrapper

    monkeypatch.setattr(gymnasium, "make", counted("make", gymnasium.make))
    config = counted("config", gymnasium_config)
    for module in (locomotion, batched_mujoco):
        monkeypatch.setattr(module, "gymnasium_config", config)
    return counts


@pytest.mark.parametrize(
    ("name", "build"),
    [
        ("gymnasium_env batched x4", lambda: locomotion.gymnasium_env("Hopper-v5", num_envs=4, num_threads=2)),
        ("gymnasium_env gymnasium x1", lambda: locomotion.gymnasium_env("Hopper-v5")),
        ("BatchedMujocoEnv", lambda: BatchedMujocoEnv("Ant-v5", 2)),
        ("make_base_env", lambda: locomotion.make_base_env("Walker2d-v5")),
        ("locomotion_task", lambda: locomotion.locomotion_task("Humanoid-v5")),
    ],
    ids=lambda v: v if isinstance(v, str) else "",
)
def test_one_gymnasium_env_is_made_and_the_keywords_are_checked_once(
    monkeypatch: pytest.MonkeyPatch, name: str, build: Callable[[], Any]
) -> None:
    """Before, ``gymnasium_env`` made two Gymnasium envs and checked its keywords twice (both backends)."""
    counts = _count(monkeypatch)
    built = build()
    assert counts == {"make": 1, "config": 1}, name
    if hasattr(built, "close"):
        built.close()


def test_a_parallel_env_preset_makes_one_env_besides_torchrls_probe(monkeypatch: pytest.MonkeyPatch) -> None:
    """``backend="gymnasium"`` with several envs: one env for the task, one for TorchRL's metadata probe.

    ``ParallelEnv`` runs its env constructor (``make_base_env``, which checks the keywords) once in this
    process to read the specs; its workers make their own envs when it starts (not here).
    """
    counts = _count(monkeypatch)
    locomotion.gymnasium_env("Hopper-v5", num_envs=2, backend="gymnasium")
    assert counts == {"make": 2, "config": 2}


def test_the_batched_preset_uses_the_facts_it_was_handed(monkeypatch: pytest.MonkeyPatch) -> None:
    """The batched env built by gymnasium_env holds the model of the one Gymnasium env that was made."""
    made: list[Any] = []
    make = gymnasium.make

    def recording(*args: Any, **kwargs: Any) -> Any:
        made.append(make(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(gymnasium, "make", recording)
    env = locomotion.gymnasium_env("Swimmer-v5", num_envs=2, frame_skip=2)
    assert len(made) == 1 and env.base_env.model is made[0].unwrapped.model
    assert env.base_env.frame_skip == 2
    env.close()


def test_the_record_module_is_the_bottom_of_envs() -> None:
    """Importing the records imports neither the batched env, nor the presets, nor the task transform."""
    code = (
        "import sys, torchtasks.envs.gymnasium_v5\n"
        "print(' '.join(m for m in ('torchtasks.envs.batched_mujoco', 'torchtasks.envs.locomotion',"
        " 'torchtasks.transforms') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert result.stdout.strip() == ""
