"""Hindsight goal relabelling with a torchtasks task as the ``reward_fn`` of TorchRL's ``HERReplayBuffer``.

What it shows: one task object decides the rewards online (inside the env, through
:class:`~torchtasks.transforms.TaskTransform`) and offline (in the replay buffer, through
``TaskTransform.reward_fn``), so relabelled rewards are exactly the task's reward for the new goal.

Set-up:

- A goal-reaching task on the batched torch pendulum (:class:`~torchtasks.envs.PendulumEnv`, state
  ``[θ, θ̇]``, θ = 0 upright): reach ``state_des = [θ_goal, 0]`` (the angle error is wrapped), reward
  ``-(Δθ² + 0.1·Δθ̇² + 0.001·u²)``, success when ``‖[Δθ, Δθ̇]‖ < SUCCESS_RADIUS``, +10 paid once on
  success (a :class:`~torchtasks.tasks.FinalRewardTask` around a
  :class:`~torchtasks.tasks.RadiallySymmetricDesiredStateTask`).
- The desired state is per-environment task memory: the desired-state task keeps ``"state_des"``
  and the final-reward wrapper nests it, so it lives at ``("task", "wrapped", "state_des")`` of
  every transition. Each environment draws a new goal angle at every reset
  (``TaskTransform(reset_overrides=sample_goals)``; :func:`sample_goals` is a module-level function,
  so the transform stays picklable for multi-process collectors).
- A ``Collector`` with a random policy fills a ``HERReplayBuffer`` whose ``goal_key`` is that memory
  entry, whose achieved goal is the next state and whose ``reward_fn`` is the transform's. A
  collector batch is ``[envs, steps]`` and the buffer is flat, so the cut at the end of each env's
  row is marked as an episode boundary (``("next", "segment_end")``, the buffer's ``end_key``):
  the buffer never picks a "future" goal from another environment's row.
- A sample is drawn; for the relabelled part the rewards are recomputed here through the task's
  functional protocol (``step_reward``, ``has_succeeded``, ``final_reward`` on the stored memory with
  the new goal) and compared with the buffer's (``assert``). The fraction of successful transitions
  before relabelling (original goals) and after (hindsight goals) is printed.

Run: ``python examples/her_relabel.py [--quick] [--strategy future|final|episode|random]``
(``--quick``: a few thousand frames, seconds; used by the tests).
"""

from __future__ import annotations

import functools
import math

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import HERReplayBuffer, LazyTensorStorage
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import FinalRewardTask, RadiallySymmetricDesiredStateTask, Task, proximity_succeeded
from torchtasks.transforms import TaskTransform

MAX_STEPS = 50  # episode time limit (StepCounter)
SUCCESS_RADIUS = 0.3  # ‖[Δθ, Δθ̇]‖ below this is a success
SUCCESS_REWARD = 10.0  # paid once, on success
GOAL_KEY = ("task", "wrapped", "state_des")  # where FinalRewardTask(DesiredStateTask) keeps the goal
ACHIEVED_KEY = ("next", "observation")  # the state a transition reached
SEGMENT_END_KEY = ("next", "segment_end")  # episode ends and the cuts between collector rows


def make_task() -> FinalRewardTask:
    """Reach ``[θ_goal, 0]`` (angle error wrapped); +``SUCCESS_REWARD`` once on success."""
    inf = float("inf")
    spec = EnvSpec(Box([-inf, -8.0], [inf, 8.0]), Box(-2.0, 2.0))
    reward = QuadraticErrorReward(Q=[1.0, 0.1], R=[1e-3])
    success = functools.partial(proximity_succeeded, threshold=SUCCESS_RADIUS)
    inner = RadiallySymmetricDesiredStateTask(spec, [0.0, 0.0], reward, indices=[0], success=success)
    return FinalRewardTask(inner, factor=SUCCESS_REWARD)


def sample_goals(init_state: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-env reset override: a goal angle uniform in [-π, π) with zero speed, for every env of the batch."""
    angle = (torch.rand(init_state.shape[:-1], dtype=init_state.dtype, device=init_state.device) * 2 - 1) * math.pi
    return {"state_des": torch.stack((angle, torch.zeros_like(angle)), dim=-1)}


def make_env(num_envs: int, seed: int = 0) -> TransformedEnv:
    """Pendulums + ``StepCounter`` + the goal-reaching task with per-env goal sampling at reset."""
    return TransformedEnv(
        PendulumEnv(batch_size=[num_envs], seed=seed),
        Compose(StepCounter(MAX_STEPS), TaskTransform(make_task(), reset_overrides=sample_goals)),
    )


def flatten_batch(batch: TensorDictBase) -> TensorDictBase:
    """``[envs, steps]`` -> ``[envs * steps]``, each env's steps in order, with its row's last step marked as a cut."""
    segment_end = batch["next", "done"].clone()
    segment_end[:, -1] = True
    batch.set(SEGMENT_END_KEY, segment_end)
    return batch.reshape(-1)


def check_goal_sampling(batch: TensorDictBase) -> int:
    """Check that each env's goal changes exactly where a new episode starts; return the number of resets."""
    goals = batch[GOAL_KEY]  # [envs, steps, 2]
    changed = (goals[:, 1:] != goals[:, :-1]).any(-1)
    started = batch["step_count"][:, 1:, 0] == 0
    assert torch.equal(changed, started), "the goal must be drawn at reset and kept for the whole episode"
    return int(started.sum())


def reward_for_goals(task: Task, data: TensorDictBase, goals: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The task's reward ``[N, 1]`` and success ``[N]`` of stored transitions if their goal had been ``goals``.

    Written with the task's functional protocol, independently of ``TaskTransform``: the stored
    memory with the new goal, the step reward on the next state, success and failure on the next
    state, and the final reward where the episode ends (success, failure or the time limit).
    """
    memory = data["task"].clone()
    memory[GOAL_KEY[1:]] = goals
    state, action = data[ACHIEVED_KEY], data["action"]
    remaining = MAX_STEPS - data["next", "step_count"][..., 0]
    step, memory = task.step_reward(state, action, memory, remaining)
    success = task.has_succeeded(state, memory)
    failure = task.has_failed(state, memory)
    ended = success | failure | data["next", "truncated"][..., 0]
    final, _ = task.final_reward(state, memory, remaining, ended)
    return (step + final).unsqueeze(-1), success


def main(quick: bool = False, strategy: str = "future", seed: int = 0) -> dict[str, float]:
    """Collect, relabel, check the relabelled rewards and print the success fractions."""
    num_envs, batches = (16, 3) if quick else (64, 20)
    frames_per_batch = num_envs * 2 * MAX_STEPS
    total_frames = batches * frames_per_batch
    sample_size = 512 if quick else 4096
    her_ratio = 0.5
    torch.manual_seed(seed)

    env = make_env(num_envs, seed)
    transform = env.transform[-1]  # the TaskTransform: its reward_fn relabels offline
    collector = Collector(env, None, frames_per_batch=frames_per_batch, total_frames=total_frames)  # random policy
    buffer = HERReplayBuffer(
        reward_fn=transform.reward_fn,
        her_ratio=her_ratio,
        strategy=strategy,
        goal_key=GOAL_KEY,
        achieved_goal_key=ACHIEVED_KEY,
        end_key=SEGMENT_END_KEY,
        storage=LazyTensorStorage(total_frames),
        batch_size=sample_size,
    )
    episodes = resets = 0
    try:
        for batch in collector:
            episodes += int(batch["next", "done"].sum())
            resets += check_goal_sampling(batch)
            buffer.extend(flatten_batch(batch))
    finally:
        collector.shutdown()
    stored = buffer[:]
    ended = f"{episodes} episode{'' if episodes == 1 else 's'} ended"
    print(f"collected {len(buffer):,} transitions from {num_envs} envs, {ended}")
    print(
        f"per-env goal sampling: checked at the {resets} episode starts inside the collected rows "
        "(the goal changes there, nowhere else)"
    )

    sample = buffer.sample()
    index = sample["index"]
    n_her = int(sample_size * her_ratio)
    relabelled, kept = sample[:n_her], sample[n_her:]
    new_goals = relabelled[GOAL_KEY]

    # the buffer's relabelled rewards are the task's rewards for the new goals
    expected, success_after = reward_for_goals(transform.task, relabelled, new_goals)
    torch.testing.assert_close(relabelled["next", "reward"], expected)
    # the rest keeps its goals and its online rewards
    assert torch.equal(kept[GOAL_KEY], stored[GOAL_KEY][index[n_her:]])
    assert torch.equal(kept["next", "reward"], stored["next", "reward"][index[n_her:]])
    print(f"relabelled rewards equal the task's reward for the new goal: {n_her} transitions checked")

    success_before = stored["next", "success"][index[:n_her], 0]  # the online verdict, original goals
    reward_before = stored["next", "reward"][index[:n_her]]
    results = {
        "success_before": success_before.float().mean().item(),
        "success_after": success_after.float().mean().item(),
        "reward_before": reward_before.mean().item(),
        "reward_after": relabelled["next", "reward"].mean().item(),
    }
    print(f"strategy {strategy!r}, {n_her} relabelled transitions of {sample_size} sampled:")
    print(f"  successful transitions before relabelling: {results['success_before']:.1%}")
    print(f"  successful transitions after relabelling:  {results['success_after']:.1%}")
    print(f"  mean reward before / after: {results['reward_before']:+.3f} / {results['reward_after']:+.3f}")
    return results


if __name__ == "__main__":
    from _cli import make_parser, quiet_torchrl

    quiet_torchrl()
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a few thousand frames (seconds)")
    parser.add_argument(
        "--strategy",
        default="future",
        choices=["future", "final", "episode", "random"],
        metavar="NAME",
        help="where new goals come from: future, final, episode or random",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    args = parser.parse_args()
    main(args.quick, args.strategy, args.seed)
