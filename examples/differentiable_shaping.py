"""Analytic policy gradients: backpropagate a torchtasks reward through a differentiable pendulum rollout.

What it shows: :class:`~torchtasks.envs.PendulumEnv` is plain torch code, and the task's rewards
(:func:`~torchtasks.envs.swing_up_task` applied by :class:`~torchtasks.transforms.TaskTransform`)
are differentiable ``nn.Module``\\ s, so ``env.rollout(policy)`` keeps the autograd graph from the
policy's parameters through the actions, the dynamics and the task to every reward. Minimising
``-mean(reward)`` with Adam trains a deterministic policy directly, with no critic, no likelihood
ratios and no exploration noise. (TorchRL collectors run under ``torch.no_grad``; ``env.rollout``
does not, which is why it is used here.)

Which part of the task gives the gradient: the swing-up task pays
``track = -(θ² + 0.1·θ̇²)`` (θ wrapped to [-π, π)) and ``effort = -0.001·u²`` at every step, and
+100 once when ``‖[wrapped θ, θ̇]‖ < 0.1`` (success, which also ends the episode). The success bonus is a
step function of the state: its derivative is zero almost everywhere, so it contributes nothing
to the gradient. All of the learning signal comes from the quadratic terms, which act as
*shaping*: they tell every pendulum, at every step, in which direction of state (and so of
torque, through the dynamics) the reward improves. PPO, by contrast, only uses reward *values*
and learns from the success bonus too. The two non-smooth spots on the way are harmless: the
angle wrap in the task has derivative 1 everywhere except at its jump (θ = ±π), and the speed
clip in the dynamics only zeroes the gradient while a pendulum spins at the bound.

Training (:class:`ShapingConfig`): 32 pendulums with the PPO example's env and task (initial
angles uniform on the circle, episodes of at most 200 steps), truncated backpropagation through
time: each iteration rolls out a 16-step window from where the previous one stopped (episodes go
on across windows; the ones that end are reset inside the rollout), backpropagates
``-mean(reward)`` through that window only, clips the gradient norm at 1 and takes an Adam step
(learning rate 1e-2). The policy sees ``[cos θ, sin θ, θ̇ / 8]`` and outputs ``2·tanh(·)`` (the
torque bound). The env, the evaluation and the plot come from ``train_swingup_ppo.py`` next to
this file.

Why short windows (16 steps = 0.8 s): near the upright state the dynamics are unstable
(linearised, ``θ̈ = 15·θ``), so the sensitivity of a late state to an early action grows like
``exp(√15·t)``: about 20× over 0.8 s but about 2·10⁵× over 64 steps (3.2 s). The gradient of a
long window is then dominated by the few pendulums that pass near the top unstabilised, and
learning is much slower (``--horizon 64``; see ``docs/training.md`` for the measured numbers).

Evaluation is the PPO example's ``evaluate``: one deterministic episode on each of 256 pendulums
from the same fixed initial states; the success rate is the fraction that end in success. The run
stops at ``--target`` (0.8) and reports the env frames it took; when ``--ppo-json`` holds a PPO
run of ``train_swingup_ppo.py``, its frames to the same target are printed next to it and its curve
is drawn in the PNG. The default ``--ppo-json`` is ``swingup_ppo_curve.json`` in ``--output`` if it
is there, else where ``train_swingup_ppo.py`` writes it by default
(``runs/train_swingup_ppo/swingup_ppo_curve.json``).

Outputs in ``--output`` (default ``runs/differentiable_shaping/``, relative to the current
directory): ``differentiable_shaping_curve.json`` and ``differentiable_shaping_curve.png``.

Run: ``python examples/differentiable_shaping.py [--quick] [--output DIR] [--seed N] [--ppo-json PATH]``
(``--quick``: a tiny run of a few seconds that runs every code path, for the tests; ``--help``
lists the hyper-parameter flags).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch
from _cli import QUICK_FOLDER, duration, frame_bar
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.envs.utils import step_mdp
from train_swingup_ppo import CURVE_NAME as PPO_CURVE_NAME
from train_swingup_ppo import DEFAULT_OUTPUT as PPO_OUTPUT
from train_swingup_ppo import MAX_TORQUE, evaluate, machine_info, make_env, mlp, save

CURVE_NAME = "differentiable_shaping_curve"
DEFAULT_OUTPUT = Path("runs/differentiable_shaping")  # relative to the current directory


@dataclass(frozen=True)
class ShapingConfig:
    """Hyper-parameters of an analytic-gradient run (``num_envs * horizon`` frames per gradient step)."""

    num_envs: int = 32
    horizon: int = 16
    learning_rate: float = 1e-2
    max_grad_norm: float = 1.0
    hidden: int = 64
    eval_every_frames: int = 8192  # as often as PPO evaluates (once per batch of 256 envs x 32 steps)
    max_minutes: float = 10.0
    target: float = 0.8


QUICK = ShapingConfig(num_envs=16, horizon=8, eval_every_frames=256, max_minutes=0.5)
QUICK_ITERATIONS = 4


class ScaledTanh(nn.Module):
    """``scale * tanh(module(x))``: squash the output of ``module`` into ``[-scale, scale]``."""

    def __init__(self, module: nn.Module, scale: float) -> None:
        super().__init__()
        self.module, self.scale = module, scale

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.scale * torch.tanh(self.module(x))


def make_policy(hidden: int) -> TensorDictModule:
    """Return a deterministic policy ``observation -> action = MAX_TORQUE * tanh(mlp(features))``."""
    return TensorDictModule(ScaledTanh(mlp(1, hidden), MAX_TORQUE), in_keys=["observation"], out_keys=["action"])


def train(config: ShapingConfig, seed: int, max_iterations: int | None = None) -> dict[str, Any]:
    """Train by backpropagation through ``env.rollout`` until the evaluation success rate reaches the target.

    Returns the run record in the format of ``train_swingup_ppo.py`` (curve of evaluation success
    rate and episode reward against frames and wall time, frames and time to the target).
    """
    torch.manual_seed(seed)
    start = time.perf_counter()
    env = make_env(config.num_envs, seed=seed)
    policy = make_policy(config.hidden)
    optimizer = torch.optim.Adam(policy.parameters(), lr=config.learning_rate)
    record: dict[str, Any] = {
        "method": "analytic gradients",
        "config": asdict(config),
        "seed": seed,
        "machine_start": machine_info(),
        "target": config.target,
        "curve": [],
        "time_to_target_s": None,
        "frames_to_target": None,
    }
    deadline = start + 60.0 * config.max_minutes
    frames = iteration = 0
    next_evaluation = config.eval_every_frames
    state = env.reset()
    bar = frame_bar(  # a frame total with max_iterations; else the run ends at the target or the time limit
        "analytic gradients",
        None if max_iterations is None else max_iterations * config.num_envs * config.horizon,
        until=f"{config.target:.0%} success or {duration(60.0 * config.max_minutes)}",
    )
    while True:
        iteration += 1
        rollout = env.rollout(config.horizon, policy, tensordict=state, auto_reset=False, break_when_any_done=False)
        loss = -rollout["next", "reward"].mean()
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(policy.parameters(), config.max_grad_norm)
        optimizer.step()
        # truncated backpropagation: the episodes go on from here, the graph behind them is dropped
        state = env.maybe_reset(step_mdp(rollout[..., -1]).detach())
        frames += rollout.numel()
        bar.update(rollout.numel())
        finished = (max_iterations is not None and iteration >= max_iterations) or time.perf_counter() > deadline
        if frames >= next_evaluation or finished:
            next_evaluation += config.eval_every_frames
            stats = evaluate(policy)
            seconds = time.perf_counter() - start
            record["curve"].append(
                {
                    "iteration": iteration,
                    "frames": frames,
                    "seconds": seconds,
                    "loss": loss.item(),
                    "eval_success_rate": stats["success_rate"],
                    "eval_episode_reward": stats["episode_reward"],
                    "eval_episode_length": stats["episode_length"],
                }
            )
            bar.set_postfix(success=f"{stats['success_rate']:.2f}", reward=f"{stats['episode_reward']:.0f}")
            if stats["success_rate"] >= config.target:
                record["time_to_target_s"], record["frames_to_target"] = seconds, frames
                finished = True
        if finished:
            break
    bar.close()
    last = record["curve"][-1]
    record.update(
        total_frames=frames,
        total_seconds=time.perf_counter() - start,
        final_success_rate=last["eval_success_rate"],
        final_episode_reward=last["eval_episode_reward"],
        machine_end=machine_info(),
    )
    return record


def default_ppo_json(output: Path, quick: bool) -> Path:
    """``swingup_ppo_curve.json`` in ``output`` if it is there, else in ``train_swingup_ppo.py``'s default output
    (that of its ``--quick`` runs for a ``--quick`` run: a smoke run compares with a smoke run)."""
    beside = output / f"{PPO_CURVE_NAME}.json"
    ppo_output = PPO_OUTPUT / QUICK_FOLDER if quick else PPO_OUTPUT
    return beside if beside.is_file() else ppo_output / f"{PPO_CURVE_NAME}.json"


def compare(record: dict[str, Any], ppo_json: Path) -> dict[str, Any] | None:
    """Print the frames this run and the PPO run in ``ppo_json`` needed; return the PPO run (None if absent)."""
    print(f"analytic gradients: {_frames_to_target(record)}")
    if not ppo_json.is_file():
        where = "" if ppo_json.parent == PPO_OUTPUT else f" --output {ppo_json.parent}"
        print(f"no PPO run at {ppo_json}: run examples/train_swingup_ppo.py{where} to compare")
        return None
    ppo = json.loads(ppo_json.read_text())
    print(f"PPO ({ppo_json}): {_frames_to_target(ppo)}")
    if record["frames_to_target"] is not None and ppo["frames_to_target"] is not None:
        print(f"frames ratio PPO / analytic gradients: {ppo['frames_to_target'] / record['frames_to_target']:.2f}")
    return ppo


def _frames_to_target(record: dict[str, Any]) -> str:
    frames, seconds = record["frames_to_target"], record["time_to_target_s"]
    if frames is None:
        return f"{record['target']:.0%} success not reached in {record['total_frames']} frames"
    return f"{record['target']:.0%} success after {frames} frames ({seconds:.1f} s)"


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSON and PNG")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument(
        "--ppo-json",
        type=Path,
        metavar="PATH",
        help="PPO run to compare with "
        + default_text(f"{PPO_CURVE_NAME}.json in --output if there, else in {PPO_OUTPUT}"),
    )
    parser.add_argument(
        "--max-minutes", type=float, help=f"wall-clock limit in minutes {default_text(ShapingConfig.max_minutes)}"
    )
    parser.add_argument(
        "--target", type=float, help=f"stop at this success rate, above 1: never {default_text(ShapingConfig.target)}"
    )
    parser.add_argument(
        "--num-envs", type=int, help=f"pendulums, stepped as one batch {default_text(ShapingConfig.num_envs)}"
    )
    parser.add_argument(
        "--horizon", type=int, help=f"backpropagation window in steps {default_text(ShapingConfig.horizon)}"
    )
    parser.add_argument(
        "--learning-rate", type=float, help=f"Adam's learning rate {default_text(ShapingConfig.learning_rate)}"
    )
    args = parser.parse_args()
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # the ops are small: a second intra-op thread costs more than it gives (measured)
    config = QUICK if args.quick else ShapingConfig()
    overrides = {
        name: getattr(args, name)
        for name in ("max_minutes", "target", "num_envs", "horizon", "learning_rate")
        if getattr(args, name) is not None
    }
    config = replace(config, **overrides)
    record = train(config, args.seed, max_iterations=QUICK_ITERATIONS if args.quick else None)
    ppo = compare(record, args.ppo_json or default_ppo_json(args.output, args.quick))
    if ppo is not None:
        record["ppo"] = {key: ppo[key] for key in ("seed", "config", "frames_to_target", "time_to_target_s")}
    title = f"Analytic policy gradients, {config.num_envs} envs, {config.horizon}-step windows, seed {args.seed}"
    json_path, png_path = save(record, args.output, CURVE_NAME, title, others=None if ppo is None else {"PPO": ppo})
    print(f"wrote {json_path} and {png_path}")


if __name__ == "__main__":
    from _cli import add_output_argument, default_text, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
