"""PPO on Hopper-v5, trained on the nominal model or with randomized masses and frictions, tested on perturbed models.

What it shows: :class:`~torchtasks.transforms.DomainRandomization` on the batched MuJoCo env, twice:
for training (every env draws a new body-mass factor and a new friction factor at each of its resets,
as Pyrado's ``DomainRandWrapperLive``) and for a robustness evaluation (a stored set of domains, the
grid, one per env: ``when="startup"`` with ``cycle``, as Pyrado's ``DomainRandWrapperBuffer``). A plain
robust-policy comparison: the policy sees only the normalised observation, never the drawn values.

Set-up: PPO exactly as ``train_locomotion_ppo.py`` (its :class:`LocomotionPPOConfig` defaults and its
training loop, imported from there: 64 envs x 32 steps per batch, ``VecNormV2`` observations, return
scaling, ``ClipPPOLoss``, 10 epochs of minibatches of 128, Adam 3e-4 annealed; 1M frames per run) on
``gymnasium_env("Hopper-v5", num_envs=64, backend="batched")``, in two variants:

- ``nominal``: the preset as it is (Gymnasium's Hopper model);
- ``randomized``: the preset plus ``DomainRandomization([UniformDomainParam("body_mass_scale", mean=1.0,
  halfspan=0.5), UniformDomainParam("geom_friction_scale", mean=1.0, halfspan=0.5)], seed=seed)``:
  every body's mass and inertia times U[0.5, 1.5], every geom's sliding friction times U[0.5, 1.5], drawn
  per env at each of its resets. The periodic evaluations of the training curve run the nominal model.

Grid evaluation, after training: the deterministic policy (the mean action; the observation
normalised with the training statistics, frozen) on 25 models, total mass x {0.5, 0.75, 1, 1.25,
1.5} times friction x {0.5, 0.75, 1, 1.25, 1.5} (``body_mass_scale``, ``geom_friction_scale``), with
``--eval-episodes`` E episodes per model from fixed initial states: ONE batched env of 25 E envs whose
``DomainRandomization(..., when="startup", cycle=grid)`` gives env i the grid point i // E (mass-major)
at its first reset; the example checks the values the envs drew against the grid and records them.
Each env's score is the return of its first episode (Hopper's episodes end when it is unhealthy): the
episode sum at its first done frame, or the running sum after ``eval_steps`` (1000) steps if it never
ended. Per grid point: the mean and the standard deviation (ddof 0) over the episodes; and their mean
over the grid.

Outputs in ``--output`` (default ``runs/train_hopper_domain_randomization``): ``dr_<variant>_seed<N>.json``
per run (config, frames, seconds, machine load, the training curve, the grid evaluation with every env's
domain, return and length), and, from every such JSON in that folder (so ``--variants nominal`` and
``--variants randomized`` run as two processes give the same outputs as one command): ``robustness.md``
(a table per variant, rows mass factor, columns friction factor, mean ± std over the episodes of every
seed; frames, seeds, wall time) and ``robustness.png`` (a heatmap per variant of the mean return, one
colour scale; needs matplotlib, the ``plot`` extra: without it the plot is skipped with a message).

Run: ``python examples/train_hopper_domain_randomization.py [--variants nominal randomized] [--seeds 0 1 2]
[--total-frames N] [--eval-episodes E] [--max-minutes X] [--quick]`` (runs one after the other; a 1M-frame
run takes over 20 minutes on 2 cores, so ``--max-minutes 60`` raises the 30-minute safety stop; ``--quick``: a
few seconds, every code path, for the tests). Measured results: ``docs/domain_randomization.md``.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the other examples' modules

import torch
from _cli import duration
from _ppo_common import PPO_CONFIG_HELP, pyplot
from torch import nn
from torchrl.envs import ExplorationType, VecNormV2, set_exploration_type
from train_locomotion_ppo import QUICK, LocomotionPPOConfig, make_eval_env, train_policy

from torchtasks.domain import UniformDomainParam
from torchtasks.transforms import DomainRandomization

ENV_ID = "Hopper-v5"
VARIANTS = ("nominal", "randomized")
#: the randomized fields: every body's mass (and inertia) and every geom's sliding friction, as factors
MASS, FRICTION = FIELDS = ("body_mass_scale", "geom_friction_scale")
HALFSPAN = 0.5  # the randomized variant trains on factors in U[1 - 0.5, 1 + 0.5]
GRID = (0.5, 0.75, 1.0, 1.25, 1.5)  # the factors of the evaluation grid, for each field
EVAL_EPISODES = 4
DEFAULT_OUTPUT = Path("runs/train_hopper_domain_randomization")
PLOT_NAME = "robustness.png"
TABLE_NAME = "robustness.md"

CONFIG = LocomotionPPOConfig(env_id=ENV_ID)
#: --quick: 2 batches of 4 envs x 100 steps (Hopper's episodes end early, so in both), evaluations of at most 100 steps
#: (some grid envs do not end their first episode then) with 2 episodes per grid point
QUICK_CONFIG = replace(
    QUICK, env_id=ENV_ID, rollout_steps=100, total_frames=800, minibatch_size=200, eval_every=800, eval_steps=100
)
QUICK_EVAL_EPISODES = 2


def file_name(variant: str, seed: int | str) -> str:
    return f"dr_{variant}_seed{seed}.json"


def domain_params() -> list[UniformDomainParam]:
    """The two randomized fields, each U[0.5, 1.5] (the grid evaluation reuses them with stored values)."""
    return [UniformDomainParam(name, mean=1.0, halfspan=HALFSPAN) for name in FIELDS]


def randomization(seed: int) -> list[DomainRandomization]:
    """The randomized variant's extra transform: new factors for every env at each of its resets."""
    return [DomainRandomization(domain_params(), seed=seed)]


def grid_domains(episodes: int) -> dict[str, torch.Tensor]:
    """The grid as stored domains, one per env: env ``i`` gets grid point ``i // episodes``.

    Point ``p`` is mass factor ``GRID[p // 5]`` and friction factor ``GRID[p % 5]`` (mass-major).
    """
    values = torch.tensor(GRID, dtype=torch.float64)
    mass, friction = torch.meshgrid(values, values, indexing="ij")
    return {
        MASS: mass.reshape(-1).repeat_interleave(episodes),
        FRICTION: friction.reshape(-1).repeat_interleave(episodes),
    }


@torch.no_grad()
def evaluate_grid(actor: nn.Module, config: LocomotionPPOConfig, vecnorm: VecNormV2, episodes: int) -> dict[str, Any]:
    """The deterministic policy's first-episode return in ``episodes`` envs per grid model (see the module docstring).

    One batched env of ``25 * episodes`` envs (``train_locomotion_ppo``'s evaluation env: fixed initial states,
    ``vecnorm``'s statistics frozen) with a ``DomainRandomization`` cycling through :func:`grid_domains` at
    startup; it runs until every env's first episode ended, at most ``config.eval_steps`` steps.
    """
    start = time.perf_counter()
    domains = grid_domains(episodes)
    num_envs = len(domains[MASS])
    env = make_eval_env(
        replace(config, eval_envs=num_envs),
        vecnorm,
        lambda seed: [DomainRandomization(domain_params(), when="startup", cycle=domains)],
    )
    score = torch.zeros(num_envs, dtype=torch.float64)
    length = torch.zeros(num_envs, dtype=torch.int64)
    ended = torch.zeros(num_envs, dtype=torch.bool)
    steps = 0
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        data = env.reset()
        drawn = {name: data["domain", name][:, 0].clone() for name in FIELDS}  # scalar fields: [N, 1] entries
        for name in FIELDS:  # env i must run grid point i // episodes
            if not torch.equal(drawn[name], domains[name]):
                raise RuntimeError(f"the grid env drew {name} {drawn[name].tolist()}, not {domains[name].tolist()}")
        while steps < config.eval_steps and not bool(ended.all()):
            data, next_data = env.step_and_maybe_reset(actor(data))
            steps += 1
            running = ~ended  # the envs still in their first episode: their sum and length so far
            score = torch.where(running, data["next", "episode_reward"].reshape(num_envs), score)
            length = torch.where(running, data["next", "step_count"].reshape(num_envs), length)
            ended = ended | data["next", "done"].reshape(num_envs)
            data = next_data
    env.close()
    for name in FIELDS:  # drawn at startup only: the resets after the first episodes kept every env's model
        if not torch.equal(data["domain", name][:, 0], domains[name]):
            raise RuntimeError(f"the grid env's {name} changed during the evaluation: {data['domain', name].tolist()}")
    per_point = score.reshape(len(GRID) ** 2, episodes)
    mean = per_point.mean(-1)
    return {
        "fields": list(FIELDS),
        "grid": list(GRID),
        "episodes_per_point": episodes,
        "max_steps": config.eval_steps,
        "steps": steps,
        "envs": {
            **{name: values.tolist() for name, values in drawn.items()},
            "return": score.tolist(),
            "length": length.tolist(),
            "ended": ended.tolist(),
        },
        "mean": mean.reshape(len(GRID), len(GRID)).tolist(),  # rows: mass factor, columns: friction factor
        "std": per_point.std(-1, correction=0).reshape(len(GRID), len(GRID)).tolist(),
        "grid_mean": mean.mean().item(),
        "seconds": time.perf_counter() - start,
    }


def run(config: LocomotionPPOConfig, variant: str, seed: int, episodes: int) -> dict[str, Any]:
    """Train one variant and seed, evaluate it on the grid; return the run record."""
    start = time.perf_counter()
    record, actor, vecnorm = train_policy(config, seed, randomization if variant == "randomized" else None)
    grid = evaluate_grid(actor, config, vecnorm, episodes)
    drawn_from = {
        param.name: {"distribution": type(param).__name__, "mean": param.mean.item(), "halfspan": param.halfspan.item()}
        for param in domain_params()
    }
    record.update(
        variant=variant,
        randomization=drawn_from if variant == "randomized" else None,
        grid_evaluation=grid,
        seconds=time.perf_counter() - start,
    )
    return record


# ---------------------------------------------------------------------------------------------- reports
def load_records(folder: Path) -> list[dict[str, Any]]:
    """Every run JSON of ``folder``, by variant then seed; refuses a run evaluated on another grid."""
    records = []
    for path in sorted(folder.glob(file_name("*", "*"))):
        record = json.loads(path.read_text())
        grid = record.get("grid_evaluation", {})
        if grid.get("fields") != list(FIELDS) or grid.get("grid") != list(GRID):
            raise ValueError(
                f"{path} is not a run of this example's grid ({list(FIELDS)} x {list(GRID)}): "
                f"got fields {grid.get('fields')} and grid {grid.get('grid')}"
            )
        records.append(record)
    return sorted(records, key=lambda record: (VARIANTS.index(record["variant"]), record["seed"]))


def pooled(records: Sequence[dict[str, Any]]) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Mean and std (ddof 0) ``[mass, friction]`` over the episodes of every record per grid point; episodes."""
    points = len(GRID) ** 2
    returns = [
        torch.tensor(record["grid_evaluation"]["envs"]["return"], dtype=torch.float64).reshape(points, -1)
        for record in records
    ]
    episodes = torch.cat(returns, dim=1)
    shape = (len(GRID), len(GRID))
    return episodes.mean(-1).reshape(shape), episodes.std(-1, correction=0).reshape(shape), episodes.shape[1]


def by_variant(records: Sequence[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    variants: dict[str, list[dict[str, Any]]] = {}
    for record in records:
        variants.setdefault(record["variant"], []).append(record)
    return variants


def factor(value: float) -> str:
    return f"{value:g}"


def table(records: Sequence[dict[str, Any]]) -> str:
    """``robustness.md``: a summary line per variant and the grid table of each variant."""
    variants = by_variant(records)
    steps = max(record["grid_evaluation"]["max_steps"] for record in records)
    nominal = GRID.index(1.0)
    lines = [
        f"# Robustness of PPO on {ENV_ID}: trained on the nominal model or with randomized masses and frictions",
        "",
        f"Return of the first episode (at most {steps} steps) of the deterministic policy on each model of the grid: "
        f"rows scale every body's mass (`{MASS}`), columns every geom's sliding friction (`{FRICTION}`). "
        "Each cell: mean ± std (ddof 0) over the episodes of every seed, from fixed initial states. "
        "`randomized` trained with both factors drawn from U[0.5, 1.5] at every reset.",
        "",
        "| variant | seeds | training frames per seed | wall time per seed (training + grid) "
        "| episodes per model | mean over the grid | nominal model (1, 1) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for variant, runs in variants.items():
        mean, _, episodes = pooled(runs)
        lines.append(
            f"| {variant} | {', '.join(str(run['seed']) for run in runs)} "
            f"| {', '.join(f'{frames:,}' for frames in sorted({run['total_frames'] for run in runs}))} "
            f"| {', '.join(duration(run['seconds']) for run in runs)} | {episodes} "
            f"| {mean.mean().item():,.1f} | {mean[nominal, nominal].item():,.1f} |"
        )
    for variant, runs in variants.items():
        mean, std, _ = pooled(runs)
        lines += [
            "",
            f"## {variant}",
            "",
            "| mass \\ friction | " + " | ".join(factor(value) for value in GRID) + " |",
            "| --- |" + " ---: |" * len(GRID),
        ]
        for mass, means, stds in zip(GRID, mean.tolist(), std.tolist(), strict=True):
            cells = " | ".join(f"{value:,.1f} ± {spread:,.1f}" for value, spread in zip(means, stds, strict=True))
            lines.append(f"| {factor(mass)} | {cells} |")
    return "\n".join(lines) + "\n"


def plot(records: Sequence[dict[str, Any]], path: Path) -> Path | None:
    """One heatmap per variant of the mean return over the grid, one colour scale; None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None

    variants = by_variant(records)
    means = {variant: pooled(runs)[0] for variant, runs in variants.items()}
    low = min(mean.min().item() for mean in means.values())
    high = max(mean.max().item() for mean in means.values())
    figure, axes = plt.subplots(
        1, len(means), figsize=(4.8 * len(means) + 1.2, 4.8), squeeze=False, sharey=True, layout="constrained"
    )
    for axis, (variant, mean) in zip(axes[0], means.items(), strict=True):
        image = axis.imshow(mean.numpy(), origin="lower", cmap="viridis", vmin=low, vmax=high)
        middle = (low + high) / 2
        for row in range(len(GRID)):
            for col in range(len(GRID)):
                value = mean[row, col].item()
                colour = "black" if value > middle else "white"
                axis.text(col, row, f"{value:.0f}", ha="center", va="center", color=colour, fontsize=9)
        axis.set_xticks(range(len(GRID)), [factor(value) for value in GRID])
        axis.set_yticks(range(len(GRID)), [factor(value) for value in GRID])
        axis.set_xlabel(f"friction factor ({FRICTION})")
        runs = variants[variant]
        frames = ", ".join(f"{frames:,}" for frames in sorted({run["total_frames"] for run in runs}))
        seeds = f"seed{'s' if len(runs) > 1 else ''} {', '.join(str(run['seed']) for run in runs)}"
        axis.set_title(f"{variant}\n{seeds}, {frames} frames each", fontsize=10)
    axes[0, 0].set_ylabel(f"mass factor ({MASS})")
    figure.colorbar(image, ax=axes[0].tolist(), label="mean first-episode return")
    figure.suptitle(f"PPO on {ENV_ID}: deterministic return on perturbed models")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSONs, robustness.md and robustness.png")
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=VARIANTS,
        default=list(VARIANTS),
        metavar="NAME",
        help="nominal and/or randomized",
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds, trained one after the other")
    parser.add_argument(
        "--eval-episodes",
        type=int,
        default=None,
        metavar="E",
        help=f"episodes per grid model {default_text(EVAL_EPISODES, f'{QUICK_EVAL_EPISODES} with --quick')}",
    )
    config_arguments(parser, CONFIG, PPO_CONFIG_HELP, ("total_frames", "max_minutes"))
    args = parser.parse_args()
    if args.eval_episodes is not None and args.eval_episodes < 1:
        parser.error(f"--eval-episodes must be at least 1, got {args.eval_episodes}")
    output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    config = QUICK_CONFIG if args.quick else CONFIG
    overrides = {name: value for name in ("total_frames", "max_minutes") if (value := getattr(args, name)) is not None}
    config = replace(config, **overrides)
    episodes = args.eval_episodes or (QUICK_EVAL_EPISODES if args.quick else EVAL_EPISODES)
    for variant in args.variants:
        for seed in args.seeds:
            record = run(config, variant, seed, episodes)
            json_path = output / file_name(variant, seed)
            json_path.write_text(json.dumps(record, indent=2))
            grid = record["grid_evaluation"]
            nominal = GRID.index(1.0)
            batches = len(record["curve"])
            print(
                f"{variant} seed {seed}: {record['total_frames']} frames in {duration(record['total_seconds'])} "
                f"({record['frames_per_second']:.0f} frames/s, {record['total_seconds'] / batches:.2f} s per batch); "
                f"grid evaluation ({len(grid['envs']['return'])} envs, {grid['steps']} steps) "
                f"{grid['seconds']:.1f} s: mean return over the grid {grid['grid_mean']:.1f}, "
                f"nominal model {grid['mean'][nominal][nominal]:.1f}; 1-min load average "
                f"{record['machine_start']['load_1min']:.2f} at start, {record['machine_end']['load_1min']:.2f} at end"
            )
            print(f"wrote {json_path}")
    records = load_records(output)
    table_path = output / TABLE_NAME
    table_path.write_text(table(records))
    print(f"wrote {table_path} ({len(records)} run{'' if len(records) == 1 else 's'})")
    png = plot(records, output / PLOT_NAME)
    if png is not None:
        print(f"wrote {png}")


if __name__ == "__main__":
    from _cli import add_output_argument, config_arguments, default_text, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
