"""A task that ends MuJoCo episodes: ``GymEnv("HalfCheetah-v5")`` in a ``ParallelEnv`` of 2 under a collector.

The task watches three of the 17 (float64) observation entries: the torso height and pitch must stay
in a small box (failure otherwise, within tens of steps under random actions) and the forward
velocity should reach a target (success within a radius). HalfCheetah never ends an episode by
itself, so every end in the data is the task's or the StepCounter's. Checks: the collected data is
consistent (offline recomputation equals the stored rewards and flags, ``done`` exactly where
success, failure or truncation, fresh memory after every partial reset) and ``check_env_specs``
passes.
"""

from __future__ import annotations

import functools
import math

import pytest
import torch
from tensordict import TensorDictBase

pytest.importorskip("mujoco")
gym = pytest.importorskip("gymnasium")

from torchrl.collectors import Collector  # noqa: E402
from torchrl.envs import Compose, GymEnv, ParallelEnv, StepCounter, TransformedEnv  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchtasks.rewards import QuadraticErrorReward  # noqa: E402
from torchtasks.spaces import Box, EnvSpec  # noqa: E402
from torchtasks.tasks import (  # noqa: E402
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    MaskedTask,
    proximity_succeeded,
)
from torchtasks.transforms import TaskTransform  # noqa: E402

pytestmark = [pytest.mark.mujoco, pytest.mark.multiprocess, pytest.mark.xdist_group("multiprocess")]

N_OBS, N_ACT = 17, 6
HEIGHT, PITCH, SPEED = 0, 1, 8  # observation entries: torso z, torso pitch, forward velocity
MAX_STEPS = 60
HEIGHT_BOUND, PITCH_BOUND = 0.2, 0.5  # failure outside these
TARGET_SPEED, SPEED_RADIUS = 2.5, 0.2  # success within this
FRAMES_PER_BATCH, TOTAL_FRAMES = 120, 240


def _task() -> FinalRewardTask:
    inf = math.inf
    low = [-inf] * N_OBS
    high = [inf] * N_OBS
    low[HEIGHT], high[HEIGHT] = -HEIGHT_BOUND, HEIGHT_BOUND
    low[PITCH], high[PITCH] = -PITCH_BOUND, PITCH_BOUND
    spec = EnvSpec(Box(low, high), Box([-1.0] * N_ACT, [1.0] * N_ACT))
    watched = [HEIGHT, PITCH, SPEED]
    reward = QuadraticErrorReward([0.0, 0.0, 1.0], [1e-3] * N_ACT)
    success = functools.partial(proximity_succeeded, threshold=SPEED_RADIUS, dims=[2])
    inner = DesiredStateTask(spec.select_state(watched), [0.0, 0.0, TARGET_SPEED], reward, success)
    return FinalRewardTask(MaskedTask(spec, inner, watched), FinalRewardMode(), factor=10.0)


def _transforms() -> Compose:
    return Compose(StepCounter(MAX_STEPS), TaskTransform(_task()))


def make_cheetah_env() -> TransformedEnv:
    """ParallelEnv of 2 HalfCheetah-v5 (spawn-safe constructors), the task on the batch."""
    base = ParallelEnv(2, functools.partial(GymEnv, "HalfCheetah-v5"), mp_start_method="fork")
    return TransformedEnv(base, _transforms())


@pytest.fixture
def keep_threads():
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def collected() -> TensorDictBase:
    threads = torch.get_num_threads()
    torch.manual_seed(0)
    collector = Collector(make_cheetah_env, None, frames_per_batch=FRAMES_PER_BATCH, total_frames=TOTAL_FRAMES)
    try:
        collector.set_seed(0)
        data = torch.cat([batch.clone() for batch in collector], dim=-1)
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    return data


def test_env_specs(keep_threads) -> None:
    env = make_cheetah_env()
    try:
        assert env.observation_spec["observation"].dtype == torch.float64
        assert env.observation_spec["observation"].shape == (2, N_OBS)
        check_env_specs(env, seed=0)
    finally:
        env.close()


def test_collected_frames(collected: TensorDictBase) -> None:
    assert collected.shape == (2, TOTAL_FRAMES // 2)
    for key in ("task", ("next", "task"), ("next", "success"), ("next", "failure"), ("next", "task_reward")):
        assert key in collected.keys(True), key


def test_episodes_end_by_the_task(collected: TensorDictBase) -> None:
    nxt = collected["next"]
    done, success, failure, truncated = (nxt[key].squeeze(-1) for key in ("done", "success", "failure", "truncated"))
    # seeded (collector and policy): these counts are deterministic, the bounds only ask for variety
    assert failure.sum() >= 4 and success.any() and truncated.any()
    assert torch.equal(done, success | failure | truncated)
    assert torch.equal(nxt["terminated"].squeeze(-1), success | failure)
    assert (done[0] != done[1]).any()  # the two envs end independently
    # failures are exactly the states outside the box, successes those near the target speed, by hand
    state = nxt["observation"]
    outside = (state[..., HEIGHT].abs() > HEIGHT_BOUND) | (state[..., PITCH].abs() > PITCH_BOUND)
    assert torch.equal(failure, outside)
    assert torch.equal(success, (state[..., SPEED] - TARGET_SPEED).abs() < SPEED_RADIUS)


def test_recomputed_rewards_equal_stored(collected: TensorDictBase) -> None:
    transform = TaskTransform(_task().double(), max_steps=MAX_STEPS)
    stored = collected.reshape(-1)
    recomputed = transform.forward(stored.clone())
    assert stored["next", "reward"].dtype == torch.float32  # the reward spec's dtype
    for key in [("next", "reward"), ("next", "success"), ("next", "failure"), ("next", "done")]:
        # offline there is no reward spec: the float64 task reward is compared in the stored dtype
        assert torch.equal(recomputed[key].to(stored[key].dtype), stored[key]), key
    # the reward by hand: velocity tracking and action cost, ±10 at success / failure
    state, action = stored["next", "observation"], stored["action"].double()
    nxt = stored["next"]
    step = -((TARGET_SPEED - state[..., SPEED]) ** 2) - 1e-3 * (action**2).sum(-1)
    final = 10.0 * (nxt["success"] & ~nxt["failure"]).squeeze(-1).double() - 10.0 * nxt["failure"].squeeze(-1).double()
    torch.testing.assert_close(nxt["reward"].squeeze(-1).double(), step + final, rtol=1e-5, atol=1e-4)


def test_partial_resets_give_fresh_memory(collected: TensorDictBase) -> None:
    done = collected["next", "done"].squeeze(-1)
    steps = collected.shape[1]
    resets = 0
    for b in range(2):
        for t in range(steps - 1):
            if done[b, t]:
                resets += 1
                assert int(collected["step_count"][b, t + 1]) == 0
                assert not collected["task", "paid"][b, t + 1]
            else:
                assert (collected["task"][b, t + 1] == collected["next", "task"][b, t]).all()
                assert int(collected["step_count"][b, t + 1]) == int(collected["next", "step_count"][b, t])
    assert resets >= 2
