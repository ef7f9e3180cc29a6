"""Train a pendulum swing-up with TorchRL's PPO, rewarded and ended by a torchtasks task.

What it shows: a batched torch env (:class:`~torchtasks.envs.PendulumEnv`, ``num_envs`` pendulums
stepped as one tensor) whose reward, success and episode end all come from a torchtasks task
(:func:`~torchtasks.envs.swing_up_task`: a ``RadiallySymmetricDesiredStateTask`` with quadratic
``track``/``effort`` terms inside a ``FinalRewardTask`` paying +100 on success) applied by
:class:`~torchtasks.transforms.TaskTransform`, trained with the standard TorchRL PPO recipe
(``Collector``, ``GAE``, ``ClipPPOLoss``, a ``ProbabilisticActor`` with a ``TanhNormal`` and a
``ValueOperator``) on CPU.

Set-up:

- The task reads the raw state ``[θ, θ̇]`` (θ = 0 upright, not wrapped); the policy and the critic
  see ``[cos θ, sin θ, θ̇ / 8]`` (:class:`PendulumFeatures`, the first layer of both networks).
- Success: ``‖[wrapped θ, θ̇]‖ < 0.1`` (the default of ``swing_up_task``); it ends the episode and
  pays +100. Episodes are truncated after ``MAX_STEPS = 200`` steps (10 s at dt = 0.05 s) by a
  ``StepCounter``. Initial states: θ uniform on the circle, θ̇ uniform in [-1, 1].
- Success rate = fraction of evaluation episodes that end in success: a separate deterministic
  rollout (the mean action of the policy) of ``EVAL_ENVS = 256`` pendulums from fixed random
  initial states (seed ``EVAL_SEED``), one episode each (every episode ends within
  ``MAX_STEPS``, by success or truncation), after every training batch. The JSON also has the
  success rate and mean episode reward of the episodes that ended in each training batch (noisy,
  and biased towards successes at the start, when no episode has reached the time limit yet).
- PPO (:class:`PPOConfig`): batches of 256 envs × 32 steps, GAE (γ = 0.98, λ = 0.95) on rewards
  scaled by 0.01 (the logged episode rewards are not scaled), 8 epochs of minibatches of 1024,
  clip 0.2, Adam 1e-3, gradient norm clipped at 1, two 64-unit tanh layers for actor and critic.
- One torch thread: the ops are small (a few hundred envs), and on this shared 2-core machine a
  second intra-op thread made them slower, not faster (see ``docs/training.md``).

Training stops when the evaluation success rate reaches ``--target`` (0.8) or after
``--max-minutes`` (10). Outputs in ``--output`` (default ``runs/train_swingup_ppo/``, relative to the
current directory): ``swingup_ppo_curve.json`` (the learning curve: success rate and mean episode
reward against frames and wall time, the time and frames to the target, the machine load) and
``swingup_ppo_curve.png``.

Run: ``python examples/train_swingup_ppo.py [--quick] [--output DIR] [--seed N] [--max-minutes M]``
(``--quick``: a tiny run of a few seconds that runs every code path, for the tests; ``--help``
lists the hyper-parameter flags).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from _ppo_common import (
    EVAL_ENVS,
    EVAL_SEED,
    MAX_SPEED,
    MAX_STEPS,
    MAX_TORQUE,
    QUICK,
    QUICK_ITERATIONS,
    PendulumFeatures,
    PPOConfig,
    machine_info,
    make_pendulum_env,
    make_policy,
    mlp,
    plot,
    save,
)
from _ppo_common import evaluate as evaluate_on
from _ppo_common import train as train_on
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv

from torchtasks.envs import swing_up_task

# the building blocks live in _ppo_common.py (shared with potential_shaping.py); they are importable from here too
__all__ = [
    "EVAL_ENVS",
    "EVAL_SEED",
    "MAX_SPEED",
    "MAX_STEPS",
    "MAX_TORQUE",
    "QUICK",
    "QUICK_ITERATIONS",
    "PPOConfig",
    "PendulumFeatures",
    "evaluate",
    "machine_info",
    "make_env",
    "make_policy",
    "mlp",
    "plot",
    "save",
    "train",
]

SUCCESS_THRESHOLD = 0.1  # ‖[wrapped θ, θ̇]‖ below this ends the episode in success
CURVE_NAME = "swingup_ppo_curve"
DEFAULT_OUTPUT = Path("runs/train_swingup_ppo")  # relative to the current directory


def make_env(num_envs: int, seed: int) -> TransformedEnv:
    """Return ``num_envs`` pendulums with ``StepCounter(MAX_STEPS)``, the swing-up task and ``RewardSum``."""
    return make_pendulum_env(swing_up_task(success_threshold=SUCCESS_THRESHOLD, max_torque=MAX_TORQUE), num_envs, seed)


def evaluate(policy: Callable[[TensorDictBase], TensorDictBase], num_envs: int = EVAL_ENVS) -> dict[str, float]:
    """Run one deterministic episode on each of ``num_envs`` pendulums from fixed initial states.

    The initial states are the same at every call (and in ``differentiable_shaping.py``): the
    evaluation env is seeded with ``EVAL_SEED``. Returns the success rate and the mean episode
    reward (task reward summed over the episode, +100 included on success) of the first episode of
    every env, and the mean episode length.
    """
    return evaluate_on(policy, make_env, num_envs)


def train(config: PPOConfig, seed: int, max_iterations: int | None = None) -> dict[str, Any]:
    """Train with PPO until the evaluation success rate reaches ``config.target`` or time runs out.

    Returns the run record: config, seed, machine load, the learning curve (one point per
    evaluation) and the wall time and frames at which the target was first reached (None if not).
    """
    return train_on(config, seed, make_env, max_iterations=max_iterations)


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSON and PNG")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument(
        "--max-minutes", type=float, help=f"wall-clock limit in minutes {default_text(PPOConfig.max_minutes)}"
    )
    parser.add_argument(
        "--target", type=float, help=f"stop at this success rate, above 1: never {default_text(PPOConfig.target)}"
    )
    parser.add_argument("--num-envs", type=int, help=f"pendulums per batch {default_text(PPOConfig.num_envs)}")
    parser.add_argument(
        "--rollout-steps", type=int, help=f"steps per env and batch {default_text(PPOConfig.rollout_steps)}"
    )
    parser.add_argument(
        "--minibatch-size", type=int, help=f"frames per PPO minibatch {default_text(PPOConfig.minibatch_size)}"
    )
    args = parser.parse_args()
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # the ops are small: a second intra-op thread costs more than it gives (measured)
    config = QUICK if args.quick else PPOConfig()
    overrides = {
        name: getattr(args, name)
        for name in ("max_minutes", "target", "num_envs", "rollout_steps", "minibatch_size")
        if getattr(args, name) is not None
    }
    config = replace(config, **overrides)
    record = train(config, args.seed, max_iterations=QUICK_ITERATIONS if args.quick else None)
    title = f"PPO swing-up, {config.num_envs} envs x {config.rollout_steps} steps per batch, seed {args.seed}"
    json_path, png_path = save(record, args.output, CURVE_NAME, title)
    reached = record["time_to_target_s"]
    print(
        f"final evaluation success rate {record['final_success_rate']:.3f} after {record['total_frames']} frames "
        f"in {record['total_seconds']:.1f} s (1-min load average {record['machine_start']['load_1min']:.1f})"
    )
    if reached is None:
        print(f"target {config.target:.0%} not reached")
    else:
        print(f"target {config.target:.0%} reached after {record['frames_to_target']} frames in {reached:.1f} s")
    print(f"wrote {json_path} and {png_path}")


if __name__ == "__main__":
    from _cli import add_output_argument, default_text, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
