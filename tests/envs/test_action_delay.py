"""BatchedMujocoEnv's action delay (``max_action_delay``): Pyrado's ActDelayWrapper per env, drawn like the physics.

The reference of the applied actions is Pyrado's definition, one ``collections.deque`` per env: at each reset the
queue holds ``delay`` zero actions; a step appends the policy's action and applies the one it pops from the front.
The reference of the physics is one ``mujoco.MjData`` per env, started from the env's state after each of its resets
and stepped by ``mj_step`` with ``ctrl = offset + scale * applied`` (the declared action map on the applied action):
``qpos`` and ``qvel`` must be equal bit for bit.
"""

from __future__ import annotations

import copy
import io
import pickle
import warnings
from collections import deque
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")

import mujoco
from tensordict import TensorDict
from torchrl.envs import Compose, TransformedEnv

from torchtasks.domain import UniformDomainParam
from torchtasks.envs import BatchedMujocoEnv, readings
from torchtasks.envs.control_suite import control_suite_env
from torchtasks.envs.mujoco_declaration import Actions, Noise, Resets
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import GoallessTask
from torchtasks.transforms import BaseEnvState, DomainRandomization, TaskTransform

pytestmark = pytest.mark.mujoco

#: a two-link arm over a floor (contacts: the solver's warm start matters), a motor with a gear and a position servo
XML = """<mujoco><option timestep="0.01"/><worldbody><geom name="floor" type="plane" size="2 2 0.1"/>
  <body name="arm" pos="0 0 0.05"><joint name="shoulder" axis="0 1 0" damping="0.05"/>
    <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
    <body name="forearm" pos="0.3 0 0"><joint name="elbow" axis="0 1 0" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/></body></body></worldbody>
  <actuator><motor joint="shoulder" gear="2" ctrlrange="-1 1"/><position joint="elbow" kp="5" ctrlrange="-1 1"/>
  </actuator></mujoco>"""
SCALE, OFFSET = np.array([0.5, 0.8]), np.array([0.1, -0.2])
NUM_ENVS, MAX_DELAY, FRAME_SKIP = 4, 3, 2


def make_base(max_action_delay: int = MAX_DELAY, num_envs: int = NUM_ENVS) -> BatchedMujocoEnv:
    return BatchedMujocoEnv(
        XML,
        num_envs,
        observation={"qpos": readings.joint_pos(), "qvel": readings.joint_vel()},
        actions=Actions(scale=SCALE.tolist(), offset=OFFSET.tolist()),
        resets=Resets(qpos_noise=Noise("uniform", 0.3), qvel_noise=Noise("uniform", 0.5)),
        frame_skip=FRAME_SKIP,
        seed=3,
        num_threads=1,
        max_action_delay=max_action_delay,
    )


def delays_drawn(when: str, every: int | None = None, seed: int = 7) -> DomainRandomization:
    """Delays in {0, 1, 2, 3}: uniform on [0, 3], rounded (Pyrado's integer domain parameter)."""
    param = UniformDomainParam("action_delay", mean=1.5, halfspan=1.5, roundint=True)
    return DomainRandomization([param], when=when, every=every, seed=seed)


def make_env(when: str = "reset", every: int | None = None) -> TransformedEnv:
    return TransformedEnv(make_base(), Compose(delays_drawn(when, every), BaseEnvState()))


def policy_actions(steps: int, seed: int = 0) -> list[torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return [torch.rand(NUM_ENVS, 2, generator=generator, dtype=torch.float64) * 2.4 - 1.2 for _ in range(steps)]


class Reference:
    """Pyrado's delay (a deque per env) and MuJoCo's own stepping, one MjData per env."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = [mujoco.MjData(model) for _ in range(NUM_ENVS)]
        self.queues: list[deque] = [deque() for _ in range(NUM_ENVS)]

    def reset(self, i: int, delay: float, qpos: torch.Tensor, qvel: torch.Tensor) -> None:
        assert delay == int(delay)
        self.queues[i] = deque([np.zeros(2)] * int(delay))
        data = self.data[i]
        mujoco.mj_resetData(self.model, data)
        data.qpos[:], data.qvel[:] = qpos.numpy(), qvel.numpy()

    def step(self, i: int, action: np.ndarray) -> np.ndarray:
        self.queues[i].append(action.copy())
        applied = self.queues[i].popleft()
        data = self.data[i]
        data.ctrl[:] = OFFSET + SCALE * applied
        for _ in range(FRAME_SKIP):
            mujoco.mj_step(self.model, data)
        return applied


def run(env: TransformedEnv, actions: list[torch.Tensor], resets: dict[int, list[int]], td: Any, ref: Reference):
    """Step ``env`` with ``actions``, resetting after step ``t`` the envs ``resets[t]``; compare with ``ref``.

    Returns the last tensordict and every step's delay entry (the domain values in the data) and active delays.
    """
    entries, active = [], []
    current = td["domain", "action_delay"][:, 0].clone()  # each env's delay of its running episode
    for t, action in enumerate(actions):
        stepped = env.step(td.set("action", action.clone()))
        assert torch.equal(stepped["action"], action)  # the data keeps the policy's action (the task reads it)
        out = stepped["next"]
        for i in range(NUM_ENVS):
            applied = ref.step(i, action[i].numpy())
            assert np.array_equal(out["applied_action"][i].numpy(), applied), (t, i)
            assert np.array_equal(out["qpos"][i].numpy(), ref.data[i].qpos), (t, i)
            assert np.array_equal(out["qvel"][i].numpy(), ref.data[i].qvel), (t, i)
        entries.append(out["domain", "action_delay"][:, 0].clone())
        active.append(current.clone())
        td = out
        if t in resets:
            mask = torch.zeros(NUM_ENVS, 1, dtype=torch.bool)
            mask[resets[t]] = True
            td = env.reset(TensorDict({"_reset": mask}, batch_size=[NUM_ENVS]))
            for i in resets[t]:
                current[i] = td["domain", "action_delay"][i, 0]
                assert not td["applied_action"][i].any()  # zeros at reset
                ref.reset(i, float(current[i]), td["qpos"][i], td["qvel"][i])
    return td, entries, active


def start(env: TransformedEnv) -> tuple[Any, Reference]:
    td = env.reset()
    ref = Reference(env.base_env.model)
    for i in range(NUM_ENVS):
        ref.reset(i, float(td["domain", "action_delay"][i, 0]), td["qpos"][i], td["qvel"][i])
    return td, ref


def test_delayed_actions_and_trajectories_equal_pyrado_and_mj_step_per_env_with_partial_resets() -> None:
    """Delays drawn per env at each reset; partial resets of different envs at different steps."""
    env = make_env("reset")
    td, ref = start(env)
    resets = {4: [0, 2], 7: [1], 9: [0, 3], 11: [2]}
    _, entries, active = run(env, policy_actions(15), resets, td, ref)
    # the draws at resets give the running episode its delay (when="reset" draws before the base env resets)
    assert all(torch.equal(entry, delay) for entry, delay in zip(entries, active, strict=True))
    delays = {int(d) for delay in active for d in delay}
    assert delays == {0, 1, 2, 3}, delays  # every delay ran (the seed is chosen so that they do)
    env.close()


def test_an_interval_draw_takes_effect_at_the_envs_next_reset_only() -> None:
    """when="interval": the drawn value is the env's next episode's delay; the running one keeps its own."""
    env = make_env("interval", every=3)
    td, ref = start(env)
    resets = {7: [0, 1], 10: [2, 3]}
    td, entries, active = run(env, policy_actions(13, seed=1), resets, td, ref)
    # the data's domain entry is the latest draw; it changed mid-episode in some env while the delay stayed
    changed = [
        (t, i)
        for t, (entry, delay) in enumerate(zip(entries, active, strict=True))
        for i in range(NUM_ENVS)
        if entry[i] != delay[i]
    ]
    assert changed
    # domain_values is the value set last: the one the next reset takes
    assert torch.equal(env.base_env.domain_values(["action_delay"])["action_delay"], entries[-1])
    env.close()


def test_the_task_judges_the_policys_action_not_the_delayed_one() -> None:
    """A control cost -|a|^2 on the policy's action: the same online as a relabelling of the stored data."""
    task = GoallessTask(EnvSpec(4, 2), QuadraticErrorReward([0.0] * 4, [1.0, 1.0]))
    env = TransformedEnv(make_base(), TaskTransform(task, state_key=["qpos", "qvel"]))
    env.base_env.set_domain({"action_delay": torch.full((NUM_ENVS,), 2.0, dtype=torch.float64)})
    td = env.reset()
    for action in policy_actions(3):
        stepped = env.step(td.set("action", action))
        expected = -(action * action).sum(-1)
        torch.testing.assert_close(stepped["next", "reward"][:, 0].to(torch.float64), expected)
        td = stepped["next"]
    assert not stepped["next", "applied_action"].equal(action)  # the physics ran another action
    env.close()


def test_a_non_finite_policy_action_breaks_the_step_it_is_given_in_and_is_never_queued() -> None:
    base = make_base()
    base.set_domain({"action_delay": torch.tensor([2.0, 2.0, 0.0, 1.0], dtype=torch.float64)})
    td = base.reset()
    first = torch.full((NUM_ENVS, 2), 0.5, dtype=torch.float64)
    td = base.step(td.set("action", first))["next"]
    before = td["qpos"].clone()
    bad = first.clone()
    bad[1, 0] = float("nan")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = base.step(td.set("action", bad))["next"]
    assert out["broken"][:, 0].tolist() == [False, True, False, False]
    assert torch.equal(out["qpos"][1], before[1])  # env 1 did not step
    # env 1 keeps its queue and its last applied action (the step's first action, delayed 2: zeros so far)
    assert out["applied_action"].tolist() == [[0.0, 0.0], [0.0, 0.0], [0.5, 0.5], [0.5, 0.5]]
    later = base.step(out.set("action", first))["next"]
    assert later["applied_action"][0].tolist() == [0.5, 0.5]  # env 0: its first action, two steps late
    assert later["applied_action"][1].tolist() == [0.0, 0.0]  # env 1: only one action queued, nothing was skipped
    assert not later["broken"].any() and torch.isfinite(later["applied_action"]).all()
    base.close()


def test_without_a_delay_there_is_no_field_entry_or_fact() -> None:
    base = make_base(0)
    assert "action_delay" not in [field.name for field in base.domain_fields()]
    assert "applied_action" not in base.observation_spec.keys()
    assert "max_action_delay" not in base.state_dict()["_extra_state"]["running_episodes"]["model"]
    hint = "'action_delay' is a domain field only of an env built with max_action_delay > 0"
    with pytest.raises(ValueError, match=hint):
        base.set_domain({"action_delay": torch.zeros(NUM_ENVS, dtype=torch.float64)})
    with pytest.raises(ValueError, match=hint):
        base.domain_fields(["action_delay"])
    draw = DomainRandomization([UniformDomainParam("action_delay", mean=1.0, halfspan=1.0, roundint=True)])
    with pytest.raises(ValueError, match=hint):  # a randomization drawing it says why, too
        TransformedEnv(base, draw).reset()
    base.close()


@pytest.mark.parametrize(
    ("value", "error", "match"),
    [(-1, ValueError, "max_action_delay must be a non-negative int, got -1"), (1.5, TypeError, "max_action_delay")],
)
def test_a_bad_max_action_delay_is_refused(value: Any, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        make_base(value)


def test_non_integer_and_too_large_delays_and_unrounded_params_are_refused() -> None:
    base = make_base()
    (field,) = base.domain_fields(["action_delay"])
    assert (field.integer, field.rule, field.nominal.item()) == (True, "integer in [0, 3]", 0.0)
    for value, shown in ((1.5, "1.5"), (4.0, "4.0")):
        values = torch.tensor([0.0, 1.0, value, 2.0], dtype=torch.float64)
        with pytest.raises(
            ValueError, match=rf"\['action_delay'\] of env 2 is {shown}, .* must be integer in \[0, 3\]"
        ):
            base.set_domain({"action_delay": values})
    with pytest.raises(ValueError, match=r"integer field 'action_delay'.*pass roundint=True"):
        UniformDomainParam("action_delay", mean=1.0, halfspan=1.0).bind_field(field)
    with pytest.raises(ValueError, match=r"can write 4\.0 into 'action_delay'"):
        UniformDomainParam("action_delay", mean=2.0, halfspan=2.0, roundint=True).bind_field(field)
    with pytest.raises(ValueError, match="pass roundint=True"):  # through the transform, at the first reset
        TransformedEnv(make_base(), DomainRandomization([UniformDomainParam("action_delay", 1.0, 1.0)])).reset()
    base.close()


def saved(state: dict[str, Any]) -> dict[str, Any]:
    """What ``torch.save`` wrote, read back as a new process reads it (``weights_only``)."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


@pytest.mark.parametrize("other", [0, 2])
def test_a_checkpoint_of_another_max_action_delay_is_refused_and_changes_nothing(other: int) -> None:
    env, stranger = make_base(), make_base(other)
    env.set_domain({"action_delay": torch.tensor([1.0, 2.0, 3.0, 0.0], dtype=torch.float64)})
    td = env.reset()
    for action in policy_actions(2):
        td = env.step(td.set("action", action))["next"]
    untouched = copy.deepcopy(env)
    stranger.reset()
    with pytest.raises(ValueError, match="max_action_delay differ"):
        env.load_state_dict(saved(stranger.state_dict()))
    with pytest.raises(ValueError, match="max_action_delay differ"):
        stranger.load_state_dict(saved(env.state_dict()))
    for action in policy_actions(4, seed=5):  # the refused load wrote nothing: env continues as its copy
        out, expected = (e.step(td.clone().set("action", action))["next"] for e in (env, untouched))
        assert (out == expected).all()
        td = out
    for e in (env, stranger, untouched):
        e.close()


# the test carries the running episodes' data across the load itself (what load_collector_state does for a collector)
@pytest.mark.filterwarnings("ignore:BaseEnvState. this env is stepped after load_state_dict:UserWarning")
def test_a_resumed_copied_or_unpickled_env_continues_bit_for_bit() -> None:
    """Mid-episode checkpoint (histories filled, delays drawn at an interval: the active and the waiting ones differ,
    partial resets after it take the waiting ones) through torch.save/load into a freshly built env (what a new
    process reads), a deep copy and a pickle (a ParallelEnv worker's)."""
    running = make_env("interval", every=2)
    td = running.reset()
    actions = policy_actions(12, seed=2)
    for t, action in enumerate(actions[:5]):
        td = running.step(td.set("action", action))["next"]
        if t == 2:
            td = running.reset(TensorDict({"_reset": torch.tensor([[True], [False], [True], [False]])}, [NUM_ENVS]))
    delay = running.base_env._delay
    waiting = running.base_env.domain_values(["action_delay"])["action_delay"].numpy()
    # what the checkpoint must carry: histories, and waiting delays other than the active ones in envs reset below
    assert delay.history.any() and (waiting != delay.delay)[[0, 1, 3]].any()
    checkpoint = saved(running.state_dict())
    resumed = make_env("interval", every=2)
    resumed.load_state_dict(checkpoint)
    copies = [resumed, copy.deepcopy(running), pickle.loads(pickle.dumps(running))]
    # a partial reset first, before another interval draw: the saved waiting delays start the new episodes
    mask = TensorDict({"_reset": torch.tensor([[True], [True], [False], [True]])}, [NUM_ENVS])
    td = running.reset(mask.clone())
    tds = [env.reset(mask.clone()) for env in copies]
    assert all((other == td).all() for other in tds)
    assert np.array_equal(delay.delay[[0, 1, 3]], waiting[[0, 1, 3]])
    for t, action in enumerate(actions[5:]):
        expected = running.step(td.set("action", action))["next"]
        for k, env in enumerate(copies):
            out = env.step(tds[k].set("action", action))["next"]
            assert (out == expected).all(), (t, k)
            tds[k] = out
        td = expected
        if t == 3:
            mask = TensorDict({"_reset": torch.tensor([[False], [True], [True], [True]])}, [NUM_ENVS])
            td = running.reset(mask.clone())
            tds = [env.reset(mask.clone()) for env in copies]
            assert all((other == td).all() for other in tds)
    assert td["domain", "action_delay"].shape == (NUM_ENVS, 1)
    for env in (running, *copies):
        env.close()


def test_a_control_suite_task_can_be_delayed() -> None:
    env = control_suite_env("cartpole-balance", 2, seed=0, max_action_delay=1)
    env.base_env.set_domain({"action_delay": torch.tensor([0.0, 1.0], dtype=torch.float64)})
    data = env.rollout(2, break_when_any_done=False)
    applied, action = data["next", "applied_action"], data["action"].to(torch.float64)
    assert torch.equal(applied[0], action[0]) and torch.equal(applied[1], torch.stack([0 * action[1, 0], action[1, 0]]))
    env.close()
