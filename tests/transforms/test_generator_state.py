"""The generators torchtasks owns are checkpoint state (issue 24, item 5): the reset generators of the torch envs
(PendulumEnv, PointMassEnv) and of BatchedMujocoEnv are in ``env.state_dict()``; after ``load_state_dict`` a fresh
env draws the initial states the saved one draws next, bit for bit, also through ``torch.save``/``torch.load``
(``weights_only``), deep copies and pickles. TorchRL's ``TransformedEnv.state_dict()`` (what ``Collector.state_dict()``
saves) holds the transforms only: the resume recipe saves ``env.base_env.state_dict()`` too. GoalCommand's state is
tested in ``test_commands.py``."""

from __future__ import annotations

import copy
import functools
import io
import pickle

import pytest
import torch
from torchrl.envs import EnvBase, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, PointMassEnv

TORCH_ENVS = {
    "pendulum": functools.partial(PendulumEnv, batch_size=[5], dtype=torch.float64),
    "point_mass": functools.partial(PointMassEnv, batch_size=[5], dtype=torch.float64),
}


def mujoco_env(seed: int | None, num_envs: int = 3) -> EnvBase:
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    from torchtasks.envs import BatchedMujocoEnv

    return BatchedMujocoEnv("Hopper-v5", num_envs=num_envs, seed=seed, num_threads=1)


def make(kind: str, seed: int | None) -> EnvBase:
    return mujoco_env(seed) if kind == "mujoco" else TORCH_ENVS[kind](seed=seed)


def run(env: EnvBase, steps: int = 4) -> None:
    """Reset, step and reset some envs only (partial resets draw from the generators too)."""
    data = env.reset()
    for i in range(steps):
        data = env.step(data.set("action", env.action_spec.zero()))["next"]
        reset = torch.zeros((*env.batch_size, 1), dtype=torch.bool)
        reset[i % env.batch_size[0]] = True
        data = env.reset(data.set("_reset", reset))


def next_states(env: EnvBase, resets: int = 3) -> list[torch.Tensor]:
    """The initial states of the next resets (BatchedMujocoEnv: ``qpos``, whose x the observation leaves out)."""
    states = []
    for _ in range(resets):
        data = env.reset()
        states.append(data["qpos"] if "qpos" in data.keys() else data["observation"])
    return states


def saved_and_loaded(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer)  # weights_only: the states are tensors, ints, strings, lists and dicts


@pytest.mark.parametrize("kind", ["pendulum", "point_mass", "mujoco"])
def test_a_loaded_env_draws_the_reset_states_of_the_uninterrupted_one(kind: str):
    env = make(kind, seed=3)
    run(env)
    state = saved_and_loaded(env.state_dict())
    assert list(state) == ["_extra_state"]
    fresh = make(kind, seed=17)
    fresh.load_state_dict(state)
    want = next_states(env)
    next_states(env)  # the saved env goes on: the loaded one has generators of its own
    for a, b in zip(want, next_states(fresh), strict=True):
        assert torch.equal(a, b)
    assert not torch.equal(want[0], next_states(make(kind, seed=17), resets=1)[0])
    for env_ in (env, fresh):
        env_.close()


@pytest.mark.parametrize("kind", ["pendulum", "point_mass", "mujoco"])
def test_copies_and_pickles_keep_the_generator_state(kind: str):
    env = make(kind, seed=4)
    run(env, steps=2)
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    states = [e.state_dict()["_extra_state"] for e in (env, *copies)]
    want = next_states(env)
    for other in copies:
        assert torch.equal(next_states(other)[0], want[0])
    if kind != "mujoco":
        for state in states[1:]:
            assert torch.equal(state["generator_state"], states[0]["generator_state"])
            assert state["seed"] == states[0]["seed"] == 4
    else:
        for state in states[1:]:
            assert state["bit_generators"] == states[0]["bit_generators"]
            running, want_running = state["running_episodes"], states[0]["running_episodes"]
            assert running["model"] == want_running["model"]
            for key in ("integration_state", "warnings", "time", "previous_position"):
                assert torch.equal(running[key], want_running[key]), key
            assert all(map(torch.equal, running["gathered"], want_running["gathered"]))
    for e in (env, *copies):
        e.close()


def test_a_transformed_env_saves_its_transforms_only_so_the_recipe_saves_the_base_env():
    env = TransformedEnv(PendulumEnv(batch_size=[2], seed=0), StepCounter(10))
    run(env)
    # TorchRL's fact: TransformedEnv.state_dict() (and Collector.state_dict()) hold no state of the base env
    assert not any(key.endswith("_extra_state") for key in env.state_dict())
    checkpoint = saved_and_loaded({"transforms": env.state_dict(), "base_env": env.base_env.state_dict()})
    fresh = TransformedEnv(PendulumEnv(batch_size=[2], seed=1), StepCounter(10))
    fresh.load_state_dict(checkpoint["transforms"])
    fresh.base_env.load_state_dict(checkpoint["base_env"])
    assert torch.equal(env.reset()["observation"], fresh.reset()["observation"])


def test_wrong_states_are_refused():
    env = PendulumEnv(batch_size=[2], seed=0)
    with pytest.raises(ValueError, match="uint8 tensor 'generator_state'"):
        env.load_state_dict({"_extra_state": {"seed": 0}})
    with pytest.raises(RuntimeError, match="Missing key"):
        env.load_state_dict({})


def test_a_mujoco_state_needs_as_many_envs():
    env, other = mujoco_env(0, num_envs=3), mujoco_env(0, num_envs=2)
    with pytest.raises(ValueError, match=r"one numpy bit_generator.state per env \(2\)"):
        other.load_state_dict(env.state_dict())
    bad = {"_extra_state": {"bit_generators": [{"bit_generator": "os"}] * 3}}
    with pytest.raises(ValueError, match=r"not a numpy bit_generator\.state"):
        env.load_state_dict(bad)
    env.close()
    other.close()
