"""Train a DeepMind Control Suite task (cheetah-run by default) with TorchRL's PPO on the batched MuJoCo env.

What it shows: :func:`~torchtasks.envs.control_suite.control_suite_env` (``num_envs`` simulations of one of
dm_control's tasks stepped by one :class:`~torchtasks.envs.BatchedMujocoEnv`, its observation entries as one flat
vector, its reward paid by a torchtasks task of reward terms, 1000-step episodes) trained with the same TorchRL PPO
as ``train_locomotion_ppo.py``: that example's config, networks, observation normalisation, return scaling,
training loop and deterministic evaluations, imported from there with the Control Suite preset in place of
Gymnasium's. Any of the suite's tasks (``--task walker-walk``); the docs report cheetah-run, walker-walk and
cartpole-swingup.

Set-up (:class:`ControlSuitePPOConfig`: ``train_locomotion_ppo.py``'s ``LocomotionPPOConfig``, CleanRL's
``ppo_continuous_action`` hyper-parameters but for the batch layout and the minibatch size):

- Env: ``control_suite_env(task, num_envs, seed=seed, flat_observation=True, num_threads=2)``, then ``VecNormV2``
  on ``"observation"``, clipping to ±10 and float32 for the policy. The task reads its float64 state unchanged.
- Reward: dm_control's, in [0, 1] per step (``ToleranceReward`` and ``ProductReward`` terms, each logged per
  episode under ``("task_reward", "episode_<term>")``); an episode is 1000 steps (dm_control's tasks never
  terminate), so a return is in [0, 1000]: the scale of the Control Suite paper's and MuJoCo Playground's returns.
- PPO: batches of 64 envs x 32 steps, GAE (γ = 0.99, λ = 0.95, the truncation bootstrapped), 10 epochs of
  minibatches of 128, ``ClipPPOLoss`` (clip 0.2, no entropy bonus, normalised advantages), a ``TanhNormal`` with a
  state-independent scale, Adam 3e-4 annealed to 0, rewards divided by the running standard deviation of the
  discounted return. One torch thread; MuJoCo on 2 threads.

Returns: the training return is the mean ``episode_reward`` (``RewardSum``'s sum of the reward over the episode)
of the training episodes that ended in a batch; all envs start together, so they end together, every
``1000 * num_envs`` frames. Every ``eval_every`` frames and at the end, a deterministic evaluation (the mean action)
runs one 1000-step episode in each of ``eval_envs`` envs from fixed initial states.

Outputs in ``--output`` (default ``runs/control_suite_ppo``): ``<task>_seed<N>.json`` per run (config, machine load,
a ``curve`` with one point per batch, an ``eval_curve``, totals, best and final returns) and
``control_suite_ppo_curve.png``: the returns of every JSON in that folder against frames, a panel per task (needs
matplotlib, the ``plot`` extra; without it the plot is skipped with a message). A table of every run in the folder
is printed at the end.

Run: ``python examples/control_suite_ppo.py [--task cheetah-run] [--seeds 0] [--total-frames N] [--quick]`` (seeds
one after the other; ``--quick``: a tiny run of a few seconds that runs every code path, for the tests; ``--help``
lists the flags). Measured results, beside published ones: ``docs/training.md``.
"""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the other examples' modules

import torch
from _cli import duration
from _ppo_common import PPO_CONFIG_HELP, config_from_args, pyplot, save_figure
from train_locomotion_ppo import FLAGS, LocomotionPPOConfig, train

from torchtasks.envs.control_suite import CONTROL_SUITE_TASKS, control_suite_env, control_suite_record

TASK = "cheetah-run"  # the default task
EPISODE_STEPS = 1000  # every Control Suite episode: its return is at most 1000
DEFAULT_OUTPUT = Path("runs/control_suite_ppo")
PLOT_NAME = "control_suite_ppo_curve.png"
#: the env factory the training loop calls as ``preset(task, num_envs=..., seed=..., num_threads=...)``
PRESET = functools.partial(control_suite_env, flat_observation=True)


@dataclass(frozen=True)
class ControlSuitePPOConfig(LocomotionPPOConfig):
    """``train_locomotion_ppo.py``'s hyper-parameters, on a Control Suite task (``env_id``: its name)."""

    env_id: str = TASK
    total_frames: int = 1_000_000
    eval_every: int = 100_000
    eval_envs: int = 16
    eval_steps: int = EPISODE_STEPS


#: --quick: two batches of 4 envs x 500 steps, so that the training episodes end (at step 1000) in the run, and one
#: evaluation of 2 envs at the end
QUICK = ControlSuitePPOConfig(
    num_envs=4, rollout_steps=500, total_frames=4000, epochs=1, minibatch_size=1000, eval_every=4000, eval_envs=2
)


def file_name(task: str, seed: int | str) -> str:
    return f"{task}_seed{seed}.json"


def run(config: ControlSuitePPOConfig, seed: int) -> dict[str, Any]:
    """Train ``config.env_id`` with one seed; the run record of ``train_locomotion_ppo.train``, with best returns."""
    record = train(config, seed, preset=PRESET)
    trained = [point for point in record["curve"] if point["train_return"] is not None]
    best_train = max(trained, key=lambda point: point["train_return"], default=None)
    best_eval = max(record["eval_curve"], key=lambda point: point["return_mean"])
    record.update(
        task=config.env_id,
        preset=f"control_suite_env({config.env_id!r}, num_envs={config.num_envs}, seed={seed}, flat_observation=True)",
        best_train_return=None if best_train is None else best_train["train_return"],
        best_train_frames=None if best_train is None else best_train["frames"],
        best_eval_return=best_eval["return_mean"],
        best_eval_frames=best_eval["frames"],
    )
    return record


def table(records: Sequence[dict[str, Any]]) -> str:
    """A Markdown table of ``records``: task, seed, frames, wall time and the final and best returns."""

    def number(value: float | None) -> str:
        return "-" if value is None else f"{value:.1f}"

    lines = [
        "| task | seed | frames | wall time | training return, last | best | evaluation return, last | best |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    order = {task: index for index, task in enumerate(CONTROL_SUITE_TASKS)}
    for record in sorted(records, key=lambda record: (order.get(record["task"], -1), record["seed"])):
        lines.append(
            f"| {record['task']} | {record['seed']} | {record['total_frames']:,} | "
            f"{duration(record['total_seconds'])} | {number(record['final_train_return'])} | "
            f"{number(record['best_train_return'])} | {record['final_eval_return']:.1f} | "
            f"{record['best_eval_return']:.1f} |"
        )
    return "\n".join(lines)


def plot(records: Sequence[dict[str, Any]], path: Path) -> Path | None:
    """Plot every run's training and evaluation returns against frames, a panel per task; None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None
    from matplotlib.ticker import EngFormatter

    tasks = {record["task"] for record in records}
    ordered = [task for task in CONTROL_SUITE_TASKS if task in tasks] + sorted(tasks - set(CONTROL_SUITE_TASKS))
    width = max(9.0, 1.0 + 4.5 * len(ordered))  # the title fits one panel too
    figure, axes = plt.subplots(1, len(ordered), figsize=(width, 4.5), sharey=True, squeeze=False)
    for axis, task in zip(axes[0], ordered, strict=True):
        runs = sorted((record for record in records if record["task"] == task), key=lambda record: record["seed"])
        for index, record in enumerate(runs):
            color = f"C{index}"
            train = [point for point in record["curve"] if point["train_return"] is not None]
            evals = record["eval_curve"]
            axis.plot(
                [point["frames"] for point in train],
                [point["train_return"] for point in train],
                color=color,
                marker=".",
                label=f"seed {record['seed']}, training episodes",
            )
            axis.plot(
                [point["frames"] for point in evals],
                [point["return_mean"] for point in evals],
                color=color,
                linestyle="--",
                marker="x",
                label=f"seed {record['seed']}, deterministic evaluation",
            )
        times = ", ".join(duration(record["total_seconds"]) for record in runs)
        axis.set_title(f"{task} ({times})")
        axis.set_xlabel("env frames")
        axis.xaxis.set_major_formatter(EngFormatter())
        axis.grid(alpha=0.3)
        axis.legend(fontsize="small", loc="upper left")
    axes[0, 0].set_ylim(0.0, EPISODE_STEPS)
    axes[0, 0].set_ylabel(f"mean episode return ({EPISODE_STEPS} steps)")
    config = records[0]["config"]
    layout = f"{config['num_envs']} envs x {config['rollout_steps']} steps per batch"
    figure.suptitle(f"PPO on the DeepMind Control Suite (BatchedMujocoEnv, {layout})")
    return save_figure(figure, path)


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSONs and PNG")
    parser.add_argument("--task", metavar="NAME", default=TASK, help="the Control Suite task, domain-task")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds, trained one after the other")
    defaults = ControlSuitePPOConfig()
    config_arguments(parser, defaults, PPO_CONFIG_HELP, FLAGS)
    args = parser.parse_args()
    try:
        task = control_suite_record(args.task).name
    except ValueError as error:
        parser.error(f"--task: {error}")
    config = config_from_args(parser, args, defaults, QUICK, env_id=task)
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    for seed in args.seeds:
        record = run(config, seed)
        json_path = args.output / file_name(task, seed)
        json_path.write_text(json.dumps(record, indent=2))
        train_return = record["final_train_return"]
        train_text = (
            "no training episode ended"
            if train_return is None
            else f"training return {train_return:.1f} (best {record['best_train_return']:.1f})"
        )
        print(
            f"{task} seed {seed}: {record['total_frames']} frames in {duration(record['total_seconds'])} "
            f"({record['frames_per_second']:.0f} frames/s; evaluation {record['eval_seconds']:.1f} s); {train_text}; "
            f"deterministic evaluation return {record['final_eval_return']:.1f} "
            f"(best {record['best_eval_return']:.1f} at {record['best_eval_frames']} frames); "
            f"1-min load average {record['machine_start']['load_1min']:.2f} at start, "
            f"{record['machine_end']['load_1min']:.2f} at end"
        )
        print(f"wrote {json_path}")
    records = [json.loads(path.read_text()) for path in sorted(args.output.glob(file_name("*", "*")))]
    print(table(records))
    png = plot(records, args.output / PLOT_NAME)
    if png is not None:
        print(f"wrote {png} ({len(records)} run{'' if len(records) == 1 else 's'})")


if __name__ == "__main__":
    from _cli import add_output_argument, config_arguments, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
