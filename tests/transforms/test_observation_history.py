"""Observation history with TorchRL's CatFrames on a batched env whose envs reset at different steps: after env i
resets, its history restarts with the reset observation repeated and the others' go on, in env.rollout and inside a
Collector, against a reference history written here from the definition (the last N observations of the episode,
oldest first, the reset observation standing in for the ones before it)."""

from __future__ import annotations

import copy

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import CatFrames, Compose, StepCounter, TransformedEnv
from torchrl.envs.transforms import Transform

from torchtasks.envs import PendulumEnv
from torchtasks.transforms import EntryNoise, ObservationNoise

N = 3  # the history's length
LIMITS = (2, 3, 5)  # each env's episode length: the envs reset at different steps


class EndAt(Transform):
    """Truncate env i's episode after ``LIMITS[i]`` steps (StepCounter alone ends every env at the same step)."""

    def __init__(self) -> None:
        super().__init__(in_keys=["step_count"], out_keys=[])

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        end = (next_tensordict["step_count"][..., 0] >= torch.tensor(LIMITS)).unsqueeze(-1)
        next_tensordict.set("truncated", next_tensordict["truncated"] | end)
        return next_tensordict.set("done", next_tensordict["done"] | end)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset


def make_env() -> TransformedEnv:
    history = CatFrames(N=N, dim=-1, in_keys=["noisy"], out_keys=["history"])
    noise = ObservationNoise({"observation": EntryNoise(std=0.1, out_key="noisy")}, seed=0)
    return TransformedEnv(
        PendulumEnv(batch_size=[len(LIMITS)], seed=0), Compose(StepCounter(100), EndAt(), noise, history)
    )


def reference(data: TensorDict) -> tuple[torch.Tensor, torch.Tensor]:
    """Each frame's history at the root and under "next", from the noisy observations and the step counts alone."""
    seen, after = data["noisy"], data["next", "noisy"]
    roots, nexts = torch.zeros(*seen.shape[:2], N * 2), torch.zeros(*seen.shape[:2], N * 2)
    for env in range(seen.shape[0]):
        stack: list[torch.Tensor] = []
        for t in range(seen.shape[1]):
            if data["step_count"][env, t, 0] == 0:  # a reset observation: the history restarts with it
                stack = [seen[env, t]] * N
            assert torch.equal(stack[-1], seen[env, t])  # the frame continues the one before
            roots[env, t] = torch.cat(stack)
            stack = [*stack[1:], after[env, t]]
            nexts[env, t] = torch.cat(stack)
    return roots, nexts


def test_catframes_restarts_each_envs_history_at_its_own_reset_in_a_rollout():
    data = make_env().rollout(11, break_when_any_done=False)
    assert (data["step_count"][:, :, 0] == 0).sum(1).tolist() == [6, 4, 3]  # each env resets on its own
    roots, nexts = reference(data)
    assert torch.equal(data["history"], roots) and torch.equal(data["next", "history"], nexts)


def test_catframes_restarts_each_envs_history_at_its_own_reset_in_a_collector():
    """Across the collector's batches too (its carried data and CatFrames' buffer go on between batches)."""
    collector = Collector(make_env, frames_per_batch=3 * 5, total_frames=3 * 10)
    data = torch.cat([batch.clone() for batch in collector], 1)
    collector.shutdown()
    roots, nexts = reference(data)
    assert torch.equal(data["history"], roots) and torch.equal(data["next", "history"], nexts)


def test_catframes_history_is_run_state_a_checkpoint_resumes():
    """CatFrames' buffer is in the env's state_dict: a fresh env loading it continues the histories bit for bit. The
    buffer is lazy (empty until the first reset, and a load into it fails): load after a reset, as into a Collector's
    env, which its construction resets."""

    def run(env: TransformedEnv, carried: TensorDict, steps: int) -> list[TensorDict]:
        frames = []
        for _ in range(steps):
            frame, carried = env.step_and_maybe_reset(carried.set("action", torch.full((len(LIMITS), 1), 0.5)))
            frames.append(frame)
        return frames, carried

    env = make_env()
    _, carried = run(env, env.reset(), 4)
    state = copy.deepcopy({"transforms": env.state_dict(), "base": env.base_env.state_dict()})  # (live references)
    expected, _ = run(env, carried.clone(), 4)
    fresh = make_env()
    fresh.reset()
    fresh.load_state_dict(state["transforms"])
    fresh.base_env.load_state_dict(state["base"])
    resumed, _ = run(fresh, carried.clone(), 4)
    assert all(torch.equal(a["next", "history"], b["next", "history"]) for a, b in zip(resumed, expected, strict=True))
