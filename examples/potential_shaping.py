"""Does potential-based shaping speed up PPO on a sparse pendulum swing-up? Measured, three seeds each.

What it shows: :class:`~torchtasks.tasks.PotentialShapingTask` wrapped around a task with a sparse
success reward, applied by :class:`~torchtasks.transforms.TaskTransform` to a batch of
:class:`~torchtasks.envs.PendulumEnv` pendulums and trained with TorchRL's PPO, against the same
task without shaping: same PPO hyper-parameters, same seeds, same frame budget, same evaluation.

Set-up (the env, networks, PPO loop and evaluation are ``train_swingup_ppo.py``'s, from
``_ppo_common.py`` next to this file):

- **Sparse task** (:func:`sparse_task`): a ``RadiallySymmetricDesiredStateTask`` toward ``[0, 0]``
  (angle error wrapped) that pays 0 per step (``ConstantReward(0.0)``), inside a
  ``FinalRewardTask(mode=FinalRewardMode(always_positive=True), factor=100)``: +100 once on
  success, nothing otherwise. Success, ``‖[wrapped θ, θ̇]‖ < 0.3`` (``--success-threshold``), ends
  the episode; episodes are truncated after 200 steps. Initial states: θ uniform on the circle, θ̇
  uniform in [-1, 1]. (With the dense task's 0.1, neither variant learned: the best evaluation
  success rate in 1M frames (seed 0) was 3.1 % without shaping and 2.3 % with it, nothing to
  compare; with 0.3 the sparse task is learned without shaping within the budget.)
- **Shaped task**: ``PotentialShapingTask(sparse_task(), potential, gamma=0.98)`` (γ = the PPO
  discount) with ``Φ(s) = −(wrapped θ)² − 0.1·θ̇²`` (:func:`potential`, the dense swing-up task's
  ``track`` term used as a potential; the same for every seed). Each step adds
  ``F = γ·Φ(s')·(1 − terminated) − Φ(s)``: success is absorbing (``F = −Φ(s)``), truncation
  bootstraps. By Ng et al. (1999) this leaves the optimal policies unchanged.
- **PPO**: ``train_swingup_ppo.py``'s defaults (:class:`PPOConfig`: 256 envs × 32 steps per batch,
  GAE γ = 0.98, λ = 0.95 on rewards scaled by 0.01, 8 epochs of minibatches of 1024, Adam 1e-3), for
  a fixed budget of ``--frames`` env frames per run (default 802,816: 800,000 rounded up to 98
  batches of 8192), with no early stop, so every run has a full learning curve.
- **Evaluation** (after every batch, for both variants on the *unshaped* sparse task, so the
  numbers compare): one deterministic episode (mean action) on each of 256 pendulums from fixed
  initial states (seed 12345); the success rate is the fraction that end in success.

Reported per run: the env frames and wall time (from the start of the run, evaluations included)
at the first evaluation with a success rate of at least ``--target`` (0.8), or "not reached", and
the final success rate. Outputs in ``--output`` (default ``runs/potential_shaping``):
``potential_shaping.json`` (every run record with its curve, the mean curve of each variant, the
set-up, the command) and ``potential_shaping.png`` (success rate and mean evaluation episode length
against frames: every seed and the mean of each variant). The runs go one after the other.

Run: ``python examples/potential_shaping.py [--quick] [--output DIR] [--seeds 0 1 2] [--frames N]``
(``--quick``: a tiny run of a few seconds that runs every code path, for the tests).
"""

from __future__ import annotations

import functools
import json
import math
import shlex
import sys
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # _ppo_common.py, also when imported from elsewhere

import torch
from _ppo_common import (
    EVAL_ENVS,
    MAX_SPEED,
    MAX_TORQUE,
    QUICK,
    PPOConfig,
    machine_info,
    make_pendulum_env,
    save_figure,
    train,
)
from torchrl.envs import TransformedEnv

from torchtasks.rewards import ConstantReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    FinalRewardMode,
    FinalRewardTask,
    PotentialShapingTask,
    RadiallySymmetricDesiredStateTask,
    Task,
    proximity_succeeded,
)

NAME = "potential_shaping"
SUCCESS_THRESHOLD = 0.3  # ‖[wrapped θ, θ̇]‖ below this is success (0.1, the dense task's, was not learned)
SUCCESS_REWARD = 100.0  # the sparse reward, paid once on success
TARGET = 0.8  # the evaluation success rate whose first crossing is reported
FRAMES = 800_000  # frame budget per run (rounded up to whole batches)
SEEDS = (0, 1, 2)
#: the variants: name -> label
VARIANTS = {"sparse": "sparse", "shaped": "sparse + shaping"}
QUICK_FRAMES = 2 * QUICK.frames_per_batch
QUICK_SEEDS = (0, 1)
QUICK_EVAL_ENVS = 32


def sparse_task(success_threshold: float = SUCCESS_THRESHOLD) -> Task:
    """Return the sparse swing-up task: 0 per step, +``SUCCESS_REWARD`` once on success (which ends the episode).

    Example:
        >>> task = sparse_task()
        >>> state = torch.tensor([[0.05, 0.0], [3.0, 0.0]])
        >>> out = task.transition(state, torch.zeros(2, 1), state, task.reset(state))
        >>> out.reward, out.success
        (tensor([100.,   0.]), tensor([ True, False]))
    """
    inf = float("inf")
    spec = EnvSpec(Box([-inf, -MAX_SPEED], [inf, MAX_SPEED]), Box(-MAX_TORQUE, MAX_TORQUE))
    success = functools.partial(proximity_succeeded, threshold=success_threshold)
    inner = RadiallySymmetricDesiredStateTask(spec, [0.0, 0.0], ConstantReward(0.0), indices=[0], success=success)
    return FinalRewardTask(inner, mode=FinalRewardMode(always_positive=True), factor=SUCCESS_REWARD)


def potential(state: torch.Tensor) -> torch.Tensor:
    """``Φ(s) = −(wrapped θ)² − 0.1·θ̇²`` of raw states ``[*B, 2]``: 0 upright at rest, −π² hanging at rest.

    Example:
        >>> potential(torch.tensor([[0.5, 1.0], [2 * math.pi + 0.5, 1.0], [math.pi, 0.0]]))
        tensor([-0.3500, -0.3500, -9.8696])
    """
    theta = torch.remainder(state[..., 0] + math.pi, 2 * math.pi) - math.pi
    return -(theta**2) - 0.1 * state[..., 1] ** 2


def shaped_task(gamma: float, success_threshold: float = SUCCESS_THRESHOLD) -> Task:
    """Return :func:`sparse_task` with potential-based shaping ``F = γ·Φ(s')·(1 − terminated) − Φ(s)``."""
    return PotentialShapingTask(sparse_task(success_threshold), potential, gamma=gamma)


def env_factories(gamma: float, success_threshold: float) -> dict[str, Any]:
    """Return the training env factory ``(num_envs, seed) -> env`` of each variant (a fresh task per env)."""

    def sparse_env(num_envs: int, seed: int) -> TransformedEnv:
        return make_pendulum_env(sparse_task(success_threshold), num_envs, seed)

    def shaped_env(num_envs: int, seed: int) -> TransformedEnv:
        return make_pendulum_env(shaped_task(gamma, success_threshold), num_envs, seed)

    return {"sparse": sparse_env, "shaped": shaped_env}


def mean_curve(runs: list[dict[str, Any]]) -> dict[str, list[float]]:
    """The mean over runs of the evaluation success rate and episode length at each frame count they all reached."""
    length = min(len(run["curve"]) for run in runs)
    points = [[run["curve"][i] for run in runs] for i in range(length)]
    return {
        "frames": [group[0]["frames"] for group in points],
        "eval_success_rate": [sum(p["eval_success_rate"] for p in group) / len(group) for group in points],
        "eval_episode_length": [sum(p["eval_episode_length"] for p in group) / len(group) for group in points],
    }


def first_crossing(curve: dict[str, list[float]], key: str, target: float) -> float | None:
    """The frame count at which ``curve[key]`` (a mean curve) first reaches ``target``, or None."""
    return next((frames for frames, value in zip(curve["frames"], curve[key], strict=True) if value >= target), None)


def run_experiment(
    config: PPOConfig,
    seeds: list[int],
    frames: int,
    success_threshold: float = SUCCESS_THRESHOLD,
    variants: list[str] | None = None,
    eval_envs: int = EVAL_ENVS,
) -> dict[str, Any]:
    """Train each variant for every seed and return the experiment record.

    The runs go one after the other, the variants alternating within each seed (sparse 0, shaped 0,
    sparse 1, ...), so that a change of the machine's load affects both variants alike.
    """
    iterations = math.ceil(frames / config.frames_per_batch)
    factories = env_factories(config.gamma, success_threshold)
    evaluation_env = factories["sparse"]  # both variants are evaluated on the unshaped task
    names = variants or list(VARIANTS)
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in names}
    for seed in seeds:
        for name in names:
            record = train(
                config,
                seed,
                factories[name],
                make_eval_env=evaluation_env,
                max_iterations=iterations,
                stop_at_target=False,
                description=f"{VARIANTS[name]}, seed {seed}",
                eval_envs=eval_envs,
            )
            record["method"] = f"PPO, {VARIANTS[name]}"
            runs[name].append(record)
            print(run_line(name, record), flush=True)
    results: dict[str, Any] = {}
    for name in names:
        curve = mean_curve(runs[name])
        results[name] = {
            "label": VARIANTS[name],
            "runs": runs[name],
            "mean_curve": curve,
            "mean_curve_frames_to_target": first_crossing(curve, "eval_success_rate", config.target),
        }
    return {
        "experiment": NAME,
        "command": " ".join(["python", *map(shlex.quote, sys.argv)]),
        "sparse_task": (
            f"0 per step, +{SUCCESS_REWARD:g} once on success (FinalRewardMode(always_positive=True)); "
            f"success: ‖[wrapped θ, θ̇]‖ < {success_threshold:g}, ends the episode; truncation after 200 steps"
        ),
        "potential": "Φ(s) = −(wrapped θ)² − 0.1·θ̇²",
        "shaping": f"F = γ·Φ(s')·(1 − terminated) − Φ(s), γ = {config.gamma:g} (the PPO discount)",
        "evaluation": f"{eval_envs} deterministic episodes on the sparse task from fixed initial states, every batch",
        "eval_envs": eval_envs,
        "success_threshold": success_threshold,
        "config": asdict(config),
        "target": config.target,
        "frame_budget": iterations * config.frames_per_batch,
        "seeds": list(seeds),
        "machine": machine_info(),
        "variants": results,
    }


def run_line(name: str, record: dict[str, Any]) -> str:
    """One line per run: frames and wall time to the target (or not reached) and the final success rate."""
    target = f"{record['target']:.0%}"
    if record["frames_to_target"] is None:
        reached = f"{target} not reached"
    else:
        reached = f"{target} after {record['frames_to_target']:,} frames ({record['time_to_target_s']:.1f} s)"
    return (
        f"{VARIANTS[name]:>16}, seed {record['seed']}: {reached}; final success rate "
        f"{record['final_success_rate']:.3f} after {record['total_frames']:,} frames ({record['total_seconds']:.1f} s)"
    )


def plot(experiment: dict[str, Any], path: Path) -> Path:
    """Plot the success rate and mean episode length against frames: every seed (thin) and the mean (thick)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter

    figure, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for color, variant in zip(("tab:blue", "tab:orange"), experiment["variants"].values(), strict=False):
        for run in variant["runs"]:
            frames = [point["frames"] for point in run["curve"]]
            for axis, key in zip(axes, ("eval_success_rate", "eval_episode_length"), strict=True):
                axis.plot(frames, [point[key] for point in run["curve"]], color=color, alpha=0.35, linewidth=0.8)
        mean = variant["mean_curve"]
        label = f"{variant['label']}: mean of seeds {', '.join(str(run['seed']) for run in variant['runs'])}"
        for axis, key in zip(axes, ("eval_success_rate", "eval_episode_length"), strict=True):
            axis.plot(mean["frames"], mean[key], color=color, linewidth=2.2, label=label)
    target = experiment["target"]
    axes[0].axhline(target, color="grey", linestyle="--", linewidth=1, label=f"target {target:.0%}")
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].set_ylabel(f"evaluation success rate ({experiment['eval_envs']} episodes)")
    axes[1].set_ylabel("mean evaluation episode length [steps]")
    for axis in axes:
        axis.set_xlabel("env frames")
        axis.xaxis.set_major_formatter(EngFormatter())
        axis.grid(alpha=0.3)
        axis.legend(loc="best", fontsize=8)
    figure.suptitle(
        f"PPO on the sparse pendulum swing-up (+{SUCCESS_REWARD:g} on ‖[θ, θ̇]‖ < {experiment['success_threshold']:g}), "
        f"with and without Φ = −θ² − 0.1·θ̇² shaping; thin: single seeds"
    )
    return save_figure(figure, path)


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, Path("runs") / NAME, "directory for the JSON and PNG")
    parser.add_argument("--seeds", type=int, nargs="+", help=f"seeds of each variant {default_text(SEEDS)}")
    parser.add_argument(
        "--frames", type=int, help=f"frame budget per run, rounded up to whole batches {default_text(FRAMES)}"
    )
    parser.add_argument("--target", type=float, default=TARGET, help="the success rate to report the frames to")
    parser.add_argument(
        "--success-threshold", type=float, default=SUCCESS_THRESHOLD, help="success: ‖[wrapped θ, θ̇]‖ below this"
    )
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=list(VARIANTS),
        metavar="NAME",
        help=f"sparse and/or shaped {default_text(list(VARIANTS))}",
    )
    args = parser.parse_args()
    args.output = output_folder(parser, args, Path("runs") / NAME)
    torch.set_num_threads(1)  # the ops are small: a second intra-op thread costs more than it gives (measured)
    config = QUICK if args.quick else PPOConfig()
    # the frame budget ends every run; the wall-clock limit is only a safety net on a very busy machine
    config = replace(config, target=args.target, max_minutes=60.0)
    seeds = args.seeds or list(QUICK_SEEDS if args.quick else SEEDS)
    frames = args.frames or (QUICK_FRAMES if args.quick else FRAMES)
    eval_envs = QUICK_EVAL_ENVS if args.quick else EVAL_ENVS
    experiment = run_experiment(config, seeds, frames, args.success_threshold, args.variants, eval_envs)
    json_path = args.output / f"{NAME}.json"
    json_path.write_text(json.dumps(experiment, indent=2))
    png_path = plot(experiment, args.output / f"{NAME}.png")
    print(f"frame budget {experiment['frame_budget']:,} per run; mean success rate over seeds {shown(seeds)}:")
    for variant in experiment["variants"].values():
        reached = variant["mean_curve_frames_to_target"]
        where = "not reached" if reached is None else f"reached after {reached:,} frames"
        final = variant["mean_curve"]["eval_success_rate"][-1]
        print(f"{variant['label']:>16}: {config.target:.0%} {where}; final {final:.3f}")
    print(f"wrote {json_path} and {png_path}")


if __name__ == "__main__":
    from _cli import add_output_argument, default_text, make_parser, output_folder, quiet_torchrl, shown

    quiet_torchrl()
    main()
