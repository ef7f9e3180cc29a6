"""Point-mass goal reaching with PPO, with and without a curriculum (per-env goal levels and an effort ramp).

The two variants differ only in the task they train on; both are evaluated on the same fixed full task:

- curriculum: ``DifficultyLevels`` keeps a level (0-4) per env that sets the box its goals are drawn from
  (half-widths 0.2, 0.35, 0.5, 0.65, 0.8 around the origin), up one after a success, down one after a
  timeout; a ``Curriculum`` ramps the effort weight linearly from 0 to its full value over ``ramp_frames``;
- baseline: goals from the full box ±0.8 and the full effort weight from the first frame.

Env and task: 128 ``PointMassEnv`` masses (force ±2 per axis) starting at rest within ±0.05 of the origin;
+1 on reaching the goal (within 0.1; ends the episode), ``-w·‖F/2‖²`` per step (w = 0.05), 50 steps at most.
Evaluation: the deterministic policy, one episode on each of 256 fixed (start, goal) pairs of the full task.
PPO (``Config``): 2,097,152 frames per run, an evaluation every 32,768. One torch thread.

Outputs in ``--output`` (default ``runs/curriculum_reaching/``): ``curriculum_reaching.json`` (config and per
run the curves: evaluation and training success rates, level fractions, effort weight) and
``curriculum_reaching.png`` (success rates; level fractions of the curriculum runs; needs matplotlib).
"""

from __future__ import annotations

import functools
import json
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # _ppo_common.py, also when imported from elsewhere

import torch
from _cli import frame_bar
from _ppo_common import machine_info, ppo_update, pyplot, save_figure
from tensordict import TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import Compose, ExplorationType, RewardSum, StepCounter, TransformedEnv, set_exploration_type
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from torchtasks.envs import PointMassEnv
from torchtasks.rewards import ControlCostReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.tasks.final_reward import FinalRewardMode
from torchtasks.transforms import Curriculum, DifficultyLevels, GoalCommand, TaskTransform, linear

NAME = "curriculum_reaching"
#: variant -> (per-env goal levels, effort ramp); the default runs compare the first two, the others are ablations
VARIANTS = {"curriculum": (True, True), "baseline": (False, False), "levels": (True, False), "ramp": (False, True)}
MAX_FORCE = 2.0
MAX_STEPS = 50  # 2.5 s per episode
START_HALF_WIDTH = 0.05  # the mass starts at rest, uniformly in [-0.05, 0.05]²
SUCCESS_RADIUS = 0.1
GOAL_HALF_WIDTHS = (0.2, 0.35, 0.5, 0.65, 0.8)  # the goal box [-h, h]² of each level; the last is the full task
EFFORT_WEIGHT = 0.05  # the full weight w of -w·‖F / MAX_FORCE‖² per step (a full push costs 2w per step)
SUCCESS_BONUS = 1.0
EVAL_ENVS = 256
EVAL_SEED = 12345
SMOOTHING = 8  # batches averaged in the plot's training success rate
EFFORT_TARGET = "wrapped_task.wrapped_task.reward.weight"  # the ControlCostReward's weight in the task tree


@dataclass(frozen=True)
class Config:
    """The PPO hyper-parameters and budgets of one run (``frames_per_batch = num_envs * rollout_steps``)."""

    num_envs: int = 128
    rollout_steps: int = 32
    total_frames: int = 2_097_152
    eval_every: int = 32_768
    ramp_frames: int = 262_144  # the curriculum's effort weight reaches its full value here
    effort_weight: float = EFFORT_WEIGHT  # the full task's w
    epochs: int = 4
    minibatch_size: int = 1024
    learning_rate: float = 3e-4
    gamma: float = 0.98
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coeff: float = 1e-3
    critic_coeff: float = 0.5
    max_grad_norm: float = 1.0
    hidden: int = 64
    target: float = 0.8  # frames to this evaluation success rate are reported

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.rollout_steps


QUICK = Config(
    num_envs=16, rollout_steps=10, total_frames=480, eval_every=160, ramp_frames=320, epochs=1, minibatch_size=80,
    hidden=16,
)  # fmt: skip
QUICK_EVAL_ENVS = 16


class StartNearOrigin(PointMassEnv):
    """``PointMassEnv`` whose masses start at rest uniformly in ``[-START_HALF_WIDTH, START_HALF_WIDTH]²``."""

    def _sample_state(self) -> torch.Tensor:
        state = super()._sample_state()
        return torch.cat((state[..., :2] * (START_HALF_WIDTH / self.bound), state[..., 2:]), dim=-1)


def make_task(effort_weight: float) -> FinalRewardTask:
    """``-w·‖F / MAX_FORCE‖²`` per step, ``+SUCCESS_BONUS`` once on reaching the goal (ends the episode)."""
    inf = float("inf")
    states = Box([-1.0, -1.0, -inf, -inf], [1.0, 1.0, inf, inf], labels=PointMassEnv.labels)
    spec = EnvSpec(states, Box([-MAX_FORCE] * 2, [MAX_FORCE] * 2))
    near = functools.partial(proximity_succeeded, threshold=SUCCESS_RADIUS)
    effort = ControlCostReward(weight=effort_weight / MAX_FORCE**2)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], effort, success=near)
    mode = FinalRewardMode(always_positive=True)
    return FinalRewardTask(MaskedTask(spec, reach, ["x", "y"]), mode, factor=SUCCESS_BONUS)


def level_change(tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> torch.Tensor:
    """Up one level after a success, down one after a timeout (a truncation without success)."""
    success = next_tensordict["success"]
    return success.long() - (next_tensordict["truncated"] & ~success).long()


def make_env(
    num_envs: int, seed: int, variant: str = "baseline", ramp_frames: int = 0, effort_weight: float = EFFORT_WEIGHT
) -> TransformedEnv:
    """Point masses with the reaching task (full effort weight w) and the goal levels and effort ramp of ``variant``."""
    levels, ramp = VARIANTS[variant]
    full = GOAL_HALF_WIDTHS[-1]
    transforms = [StepCounter(MAX_STEPS), TaskTransform(make_task(effort_weight), goal_key="goal")]
    if ramp:
        weight = linear(0.0, effort_weight / MAX_FORCE**2, start_frame=0, end_frame=ramp_frames)
        transforms.append(Curriculum({EFFORT_TARGET: weight}))
    if levels:
        low = [[-h, -h] for h in GOAL_HALF_WIDTHS]
        high = [[h, h] for h in GOAL_HALF_WIDTHS]
        transforms.append(
            DifficultyLevels(len(GOAL_HALF_WIDTHS), {"command.low": low, "command.high": high}, rule=level_change)
        )
    transforms += [GoalCommand(Box([-full, -full], [full, full]), goal_key="goal", seed=seed), RewardSum()]
    env = StartNearOrigin(batch_size=[num_envs], max_force=MAX_FORCE, seed=seed)
    return TransformedEnv(env, Compose(*transforms))


class Features(nn.Module):
    """``(observation [x, y, vx, vy], goal [gx, gy]) -> [x, y, vx, vy, gx - x, gy - y]``."""

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return torch.cat((observation, goal - observation[..., :2]), dim=-1)


class MLP(nn.Module):
    """The features followed by a two-hidden-layer tanh MLP."""

    def __init__(self, out_features: int, hidden: int) -> None:
        super().__init__()
        self.features = Features()
        self.net = nn.Sequential(
            nn.Linear(6, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(), nn.Linear(hidden, out_features)
        )

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return self.net(self.features(observation, goal))


def make_policy(env: TransformedEnv, hidden: int) -> tuple[ProbabilisticActor, ValueOperator]:
    """The actor (TanhNormal on ``±MAX_FORCE``, reading the observation and the goal) and the critic."""
    actor_net = TensorDictModule(
        _Chain(MLP(4, hidden), NormalParamExtractor()), in_keys=["observation", "goal"], out_keys=["loc", "scale"]
    )
    actor = ProbabilisticActor(
        actor_net,
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -MAX_FORCE, "high": MAX_FORCE},
        return_log_prob=True,
        default_interaction_type=ExplorationType.RANDOM,
    )
    critic = ValueOperator(MLP(1, hidden), in_keys=["observation", "goal"])
    return actor, critic


class _Chain(nn.Module):
    """``first(*inputs)`` then ``second`` (``nn.Sequential`` takes one input)."""

    def __init__(self, first: nn.Module, second: nn.Module) -> None:
        super().__init__()
        self.first, self.second = first, second

    def forward(self, *inputs: torch.Tensor) -> Any:
        return self.second(self.first(*inputs))


@torch.no_grad()
def evaluate(
    actor: ProbabilisticActor, num_envs: int = EVAL_ENVS, effort_weight: float = EFFORT_WEIGHT
) -> dict[str, float]:
    """Success rate, mean length and mean return of one deterministic episode on each fixed (start, goal) pair.

    The pairs are the same at every call (seed ``EVAL_SEED``), the goals from the full box and the effort at
    its full weight, whichever variant trained the policy.
    """
    env = make_env(num_envs, EVAL_SEED, effort_weight=effort_weight)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        data = env.rollout(MAX_STEPS, actor, break_when_any_done=False)
    nxt = data["next"]
    first_end = nxt["done"].squeeze(-1).int().argmax(dim=-1)  # every episode ends by MAX_STEPS
    rows = torch.arange(num_envs)
    return {
        "success_rate": nxt["success"].squeeze(-1)[rows, first_end].float().mean().item(),
        "episode_length": (first_end + 1).float().mean().item(),
        "episode_reward": nxt["episode_reward"].squeeze(-1)[rows, first_end].mean().item(),
    }


def level_fractions(stats: dict[str, float]) -> list[float]:
    """The fraction of envs at each level (``episode_statistics`` lists the levels up to the highest reached)."""
    return [stats.get(f"curriculum/level_fraction/{k}", 0.0) for k in range(len(GOAL_HALF_WIDTHS))]


def train(config: Config, seed: int, variant: str, eval_envs: int = EVAL_ENVS) -> dict[str, Any]:
    """One PPO run of ``variant`` for ``config.total_frames`` frames; returns its curves."""
    torch.manual_seed(seed)
    start = time.perf_counter()
    levels = VARIANTS[variant][0]
    env = make_env(config.num_envs, seed, variant, config.ramp_frames, config.effort_weight)
    actor, critic = make_policy(env, config.hidden)
    advantage = GAE(gamma=config.gamma, lmbda=config.lmbda, value_network=critic, average_gae=False)
    loss_module = ClipPPOLoss(
        actor, critic, clip_epsilon=config.clip_epsilon, entropy_coeff=config.entropy_coeff,
        critic_coeff=config.critic_coeff, loss_critic_type="l2", normalize_advantage=True,
    )  # fmt: skip
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=config.learning_rate)
    collector = Collector(
        env, actor, frames_per_batch=config.frames_per_batch, total_frames=config.total_frames,
        auto_register_policy_transforms=False,
    )  # fmt: skip
    first = evaluate(actor, eval_envs, config.effort_weight)
    curve = [{"frames": 0, "seconds": 0.0, **{f"eval_{k}": v for k, v in first.items()}}]
    train_curve: list[dict[str, Any]] = []
    frames, next_eval = 0, config.eval_every
    bar = frame_bar(f"{variant} seed {seed}", config.total_frames)
    for batch in collector:
        frames += batch.numel()
        stats = episode_statistics(batch)
        point: dict[str, Any] = {"frames": frames, "train_success_rate": stats.get("success_rate")}
        if levels:
            point["level_fractions"] = level_fractions(stats)
            point["mean_level"] = stats["curriculum/level"]
        scheduled = stats.get(f"curriculum/{EFFORT_TARGET.replace('.', '/')}")
        point["effort_weight"] = config.effort_weight if scheduled is None else scheduled * MAX_FORCE**2
        train_curve.append(point)
        with torch.no_grad():
            advantage(batch)
        ppo_update(
            loss_module, optimizer, batch.reshape(-1), epochs=config.epochs, minibatch_size=config.minibatch_size,
            max_grad_norm=config.max_grad_norm,
        )  # fmt: skip
        collector.update_policy_weights_()
        bar.update(batch.numel())
        if frames >= next_eval or frames >= config.total_frames:
            next_eval += config.eval_every
            result = evaluate(actor, eval_envs, config.effort_weight)
            curve.append(
                {
                    "frames": frames,
                    "seconds": time.perf_counter() - start,
                    **{f"eval_{k}": v for k, v in result.items()},
                }
            )
            level = {"level": f"{point['mean_level']:.1f}"} if levels else {}
            bar.set_postfix(success=f"{result['success_rate']:.2f}", **level)
    bar.close()
    collector.shutdown()
    rates = [p["eval_success_rate"] for p in curve]
    reached = next((p["frames"] for p in curve if p["eval_success_rate"] >= config.target), None)
    return {
        "variant": variant,
        "seed": seed,
        "total_frames": frames,
        "seconds": time.perf_counter() - start,
        "final_success_rate": rates[-1],
        "peak_success_rate": max(rates),
        "frames_to_target": reached,
        "curve": curve,
        "train_curve": train_curve,
        "machine_end": machine_info(),
    }


def moving_mean(values: list[float], window: int) -> list[float]:
    """The mean of each value and the ``window - 1`` before it (fewer at the start)."""
    return [sum(values[max(0, i + 1 - window) : i + 1]) / (i + 1 - max(0, i + 1 - window)) for i in range(len(values))]


def mean_curve(runs: list[dict[str, Any]], key: str) -> list[float]:
    return [sum(values) / len(values) for values in zip(*([p[key] for p in run["curve"]] for run in runs), strict=True)]


def plot(experiment: dict[str, Any], path: Path) -> Path | None:
    """Success rates per variant and the level fractions and effort weight of the curriculum runs, against frames.

    Top row: the first ``2 * ramp_frames`` frames, where the levels and the effort weight move; bottom row: the
    whole run (one row only when the run is not longer than that). Each variant has its own colour and line
    style, the curriculum thinner and drawn last (on top). Training success rates are left out before every env
    could have ended a full-length episode (the episodes that end first are the quick successes).
    """
    plt = pyplot()
    if plt is None:
        return None
    from matplotlib.ticker import EngFormatter

    variants = experiment["variants"]
    config = experiment["config"]
    total = config["total_frames"]
    first_full_episodes = config["num_envs"] * MAX_STEPS
    leveled = next((variant for variant in variants if VARIANTS[variant][0]), None)  # curriculum, or its ablation
    zoom = 2 * config["ramp_frames"]
    ends = (zoom, total) if zoom < total else (total,)  # the zoomed row only when it shows less than the whole run
    figure, axes = plt.subplots(len(ends), 2, figsize=(12, 4 * len(ends)), squeeze=False)
    colors = {"curriculum": "tab:blue", "baseline": "tab:orange", "levels": "tab:green", "ramp": "tab:purple"}
    styles = {"curriculum": "-", "baseline": "--", "levels": "-.", "ramp": (0, (6, 2, 1, 2, 1, 2))}
    palette = plt.cm.viridis([k / (len(GOAL_HALF_WIDTHS) - 1) for k in range(len(GOAL_HALF_WIDTHS))])
    widths = {"curriculum": 2.0}  # thinner than the others and drawn last: both visible where the lines coincide
    order = sorted(variants, key=lambda variant: variant == "curriculum")
    handles: dict[str, Any] = {}
    several = any(len(runs) > 1 for runs in variants.values())
    for row, end in enumerate(ends):
        success, levels = axes[row]
        span = "the whole run" if end == total else f"the first {end:,} frames (twice the effort ramp)"
        for variant in order:
            runs, color, style = variants[variant], colors[variant], styles[variant]
            for run in runs:
                if several:
                    evals = [p for p in run["curve"] if p["frames"] <= end]
                    success.plot(
                        [p["frames"] for p in evals], [p["eval_success_rate"] for p in evals], color=color, alpha=0.4
                    )
                train = [
                    p for p in run["train_curve"]
                    if p["train_success_rate"] is not None and first_full_episodes <= p["frames"] <= end
                ]  # fmt: skip
                rates = moving_mean([p["train_success_rate"] for p in train], SMOOTHING)
                success.plot([p["frames"] for p in train], rates, color=color, alpha=0.6, linestyle=":", linewidth=1)
            frames = [p["frames"] for p in runs[0]["curve"] if p["frames"] <= end]  # increasing: a prefix
            mean = mean_curve(runs, "eval_success_rate")[: len(frames)]
            seeds = f"seed {runs[0]['seed']}" if len(runs) == 1 else f"mean of {len(runs)} seeds"
            (handles[variant],) = success.plot(
                frames, mean, color=color, linestyle=style, linewidth=widths.get(variant, 3.5),
                label=f"{variant}: evaluation, {seeds}",
            )  # fmt: skip
        success.axhline(config["target"], color="grey", linestyle="--", linewidth=1)
        success.set_ylim(-0.02, 1.02)
        success.set_ylabel(f"success rate ({experiment['eval_envs']} fixed full-task goals)")
        success.set_title(f"success rates, {span}", fontsize=9)
        runs = variants.get(leveled, [])
        if runs:
            train = [[p for p in run["train_curve"] if p["frames"] <= end] for run in runs]
            frames = [p["frames"] for p in train[0]]
            fractions = [
                [sum(points[i]["level_fractions"][k] for points in train) / len(runs) for i in range(len(frames))]
                for k in range(len(GOAL_HALF_WIDTHS))
            ]
            labels = [f"level {k}: goals in ±{h}" for k, h in enumerate(GOAL_HALF_WIDTHS)]
            levels.stackplot(frames, fractions, labels=labels, colors=palette)
            weight = levels.twinx()
            effort = [sum(points[i]["effort_weight"] for points in train) / len(runs) for i in range(len(frames))]
            weight.plot(frames, effort, color="black", linewidth=1.5, label="effort weight w")
            weight.set_ylim(0, max(config["effort_weight"], 1e-6) * 1.05)
            weight.set_ylabel("effort weight w")
            if row == 0:
                levels.legend(loc="center right", fontsize=8)
                weight.legend(loc="upper right", fontsize=8)
        levels.set_ylim(0, 1)
        levels.set_ylabel(f"{leveled}: fraction of envs per level" if runs else "fraction of envs per level")
        levels.set_title(f"levels and effort weight ({leveled or 'curriculum'} runs' mean), {span}", fontsize=9)
        for axis in (success, levels):
            axis.set_xlim(0, end)
            axis.xaxis.set_major_formatter(EngFormatter())
            axis.grid(alpha=0.3)
            axis.set_xlabel("environment frames")
    axes[0, 0].legend(handles=[handles[variant] for variant in variants], loc="center right", fontsize=8)
    thin = "thin: evaluation per seed; " if several else ""
    figure.suptitle(
        "Point-mass goal reaching, PPO: a curriculum against the full task from the first frame\n"
        f"{thin}dotted: training success on its own goals ({SMOOTHING}-batch mean); dashed grey: the target",
        fontsize=11,
    )
    return save_figure(figure, path)


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, Path("runs") / NAME, "directory for the JSON and PNG")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds of each variant")
    parser.add_argument(
        "--variants", nargs="+", choices=list(VARIANTS), default=["curriculum", "baseline"], metavar="NAME",
        help="curriculum, baseline; ablations: levels (no ramp), ramp (no levels)",
    )  # fmt: skip
    parser.add_argument("--frames", type=int, help=f"frame budget per run {default_text(Config.total_frames)}")
    parser.add_argument(
        "--effort-weight", type=float, help=f"the full task's effort weight w {default_text(EFFORT_WEIGHT)}"
    )
    args = parser.parse_args()
    args.output = output_folder(parser, args, Path("runs") / NAME)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    config = QUICK if args.quick else Config()
    if args.frames is not None:
        config = replace(config, total_frames=args.frames)
    if args.effort_weight is not None:
        config = replace(config, effort_weight=args.effort_weight)
    seeds = args.seeds[:1] if args.quick else args.seeds
    eval_envs = QUICK_EVAL_ENVS if args.quick else EVAL_ENVS
    experiment: dict[str, Any] = {
        "config": asdict(config),
        "env": {
            "max_force": MAX_FORCE,
            "max_steps": MAX_STEPS,
            "start_half_width": START_HALF_WIDTH,
            "success_radius": SUCCESS_RADIUS,
            "goal_half_widths": list(GOAL_HALF_WIDTHS),
            "success_bonus": SUCCESS_BONUS,
        },
        "eval_envs": eval_envs,
        "command": " ".join(["python examples/curriculum_reaching.py", *sys.argv[1:]]),
        "machine_start": machine_info(),
        "variants": {},
    }
    start = time.perf_counter()
    for seed in seeds:
        for variant in args.variants:
            run = train(config, seed, variant, eval_envs)
            experiment["variants"].setdefault(variant, []).append(run)
            reached = run["frames_to_target"]
            what = f"after {reached:,} frames" if reached is not None else "not reached"
            print(
                f"{variant}, seed {seed}: {config.target:.0%} {what}; success final {run['final_success_rate']:.2f}, "
                f"peak {run['peak_success_rate']:.2f} ({run['seconds']:.0f} s)",
                flush=True,
            )
    for variant, runs in experiment["variants"].items():
        finals = ", ".join(f"{run['final_success_rate']:.2f}" for run in runs)
        reached = sum(run["frames_to_target"] is not None for run in runs)
        print(f"{variant}: final success {finals}; {reached} of {len(runs)} runs reached {config.target:.0%}")
    experiment["total_seconds"] = time.perf_counter() - start
    experiment["machine_end"] = machine_info()
    json_path = args.output / f"{NAME}.json"
    json_path.write_text(json.dumps(experiment, indent=1))
    print(f"wrote {json_path} ({experiment['total_seconds']:.0f} s)")
    png_path = plot(experiment, args.output / f"{NAME}.png")
    if png_path is not None:
        print(f"wrote {png_path}")


if __name__ == "__main__":
    from _cli import add_output_argument, default_text, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
