"""PPO on the velocity-tracking ("joystick") quadruped: follow a commanded planar velocity and yaw rate.

What it shows: :func:`~torchtasks.envs.velocity_tracking_env` (the shipped quadruped on the batched MuJoCo env, a
:class:`~torchtasks.transforms.GoalCommand` of ``(v_x, v_y, ω_z)`` resampled every 150 to 500 steps, zero in 10% of
the draws, and :func:`~torchtasks.tasks.velocity_tracking_task`: IsaacLab's tracking kernels and regularisers, each
logged per step and summed per episode, ending an episode on a base contact or a tilt beyond 70°), trained with
PPO and evaluated by the tracking error of the planar velocity and of the yaw rate, the falls per episode and the
return.

Set-up (:class:`VelocityPPOConfig`):

- Env: ``velocity_tracking_env(num_envs, seed=seed, curriculum_frames=...)``: 1000-step episodes (20 s at 50 Hz),
  actions joint targets ``home + 0.5 * action``, the command range ``v_x`` in ±1 m/s, ``v_y`` in ±0.5 m/s, ``ω_z``
  in ±1 rad/s, widened by a Curriculum from 30% of it over the first ``curriculum_frames`` frames; then, for the
  policy only, ``VecNormV2`` on ``"observation"``, clipping to ±10 and float32 (as ``own_robot_ppo.py``).
- PPO as ``train_locomotion_ppo.py`` (its networks and return scaling; the actions bounded to ±1 per joint, see
  :func:`make_policy`): batches of 64 envs x 32 steps, GAE
  (γ = 0.99, λ = 0.95), ``ClipPPOLoss`` (clip 0.2, normalised advantages), 5 epochs of minibatches of 512, Adam at 1e-3
  annealed linearly to 0, gradient norm clipped at 0.5; one torch thread, MuJoCo on 2 threads.
- Evaluation (:func:`evaluate`) every ``eval_every`` frames and at the end: the deterministic policy for 1000 steps
  in ``eval_envs`` envs from fixed initial states and a fixed command stream, with the full command range; the
  mean planar velocity error ``|v_xy* - v_xy|`` [m/s] and yaw-rate error ``|ω_z* - ω_z|`` [rad/s] over all frames,
  the falls (episodes ended by ``base_contact`` or ``bad_orientation``) per episode, the mean return.

Perturbations: :func:`train` and :func:`evaluate` take a list of perturbation transforms (observation noise, pushes,
randomized physics and action delays: placed by :func:`~torchtasks.envs.velocity_tracking_env` after the command and
before the policy's observation is concatenated; the envs have an action queue of ``MAX_ACTION_DELAY`` steps).
:data:`VARIANTS` (trained): ``"nominal"`` (none) and ``"robust"`` (:func:`robust_training`). :data:`CONDITIONS`
(evaluated): ``"nominal"`` and ``"pushes and delay"`` (:func:`unseen_pushes_and_delay`: stronger, more frequent
pushes and a longer delay than the robust variant trained with).

Outputs in ``--output`` (default ``runs/velocity_tracking_ppo``): ``velocity_tracking_seed<N>.json`` (config, seed,
machine load, wall time, frames, the per-batch ``curve`` with the training returns and every term's, the
``eval_curve``, and ``results``: each variant, and the baseline ``"standing still"`` (zero actions: its errors are
those of the commands), evaluated under each condition), ``velocity_tracking_seed<N>.md`` (the
tables) and ``velocity_tracking_seed<N>.png`` (tracking errors and returns against frames; needs matplotlib, the
``plot`` extra, else skipped with a message); with several seeds also ``velocity_tracking_seeds<A>-<B>.md`` (every
variant under every condition, the mean over the seeds and each seed's value, the frames and the wall times; printed
too) and ``.png`` (every seed's curves).

Run: ``python examples/velocity_tracking_ppo.py [--seeds 0 1] [--output DIR] [--quick]`` (seeds one after the other;
``--quick``: a tiny run of a few seconds that runs every code path, for the tests; ``--help`` lists the flags).
Measured results: the docs section "The velocity-tracking task".
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the other examples' modules

import torch
from _cli import duration, frame_bar, time_unit
from _ppo_common import PPO_CONFIG_HELP, config_from_args, machine_info, pyplot, save_figure
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.envs import ExplorationType, Transform, TransformedEnv, VecNormV2, set_exploration_type
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from train_locomotion_ppo import PPOLearner, RunClock, mlp, normalised, training_returns

from torchtasks.domain import UniformDomainParam
from torchtasks.envs import velocity_tracking_env, velocity_tracking_perturbations
from torchtasks.stats import episode_statistics
from torchtasks.tasks import VELOCITY_TRACKING_WEIGHTS
from torchtasks.transforms import DomainRandomization, Pushes

TERMS = tuple(VELOCITY_TRACKING_WEIGHTS)  # the task's named reward terms
FALLS = ("base_contact", "bad_orientation")  # the end conditions that are falls
EVAL_SEED = 12345  # the evaluations always start from the same initial states and command stream
DEFAULT_OUTPUT = Path("runs/velocity_tracking_ppo")

#: the envs' action queue (steps): a delay is drawn per env only where a variant or a condition draws one
MAX_ACTION_DELAY = 2
#: ``() -> perturbation transforms``: a fresh list for every env built (a transform has one env)
Perturbations = Callable[[], Sequence[Transform]]


def robust_training() -> list[Transform]:
    """The robust variant's training perturbations, :func:`~torchtasks.envs.velocity_tracking_perturbations`:
    IsaacLab's observation noise on the policy's sensed entries with per-episode biases, a push of the torso every
    5 to 10 s (up to ±0.5 m/s along x and y), an action delay of 0 or 1 step, servo stiffness x0.8 to x1.2, masses
    x0.9 to x1.1 and frictions x0.6 to x1.2, drawn per env and episode."""
    return velocity_tracking_perturbations(seed=1)


def unseen_pushes_and_delay() -> list[Transform]:
    """An evaluation condition neither variant trained under: a push of the torso every 2 to 4 s of up to
    ±1 m/s along x and y, and a 2-step action delay in every env."""
    pushes = Pushes("torso", velocity=[1.0, 1.0, 0.0, 0.0, 0.0, 0.0], interval_steps=(100, 200), seed=4)
    delay = DomainRandomization([UniformDomainParam("action_delay", 2, 0, roundint=True)], when="reset", seed=5)
    return [pushes, delay]


#: the variants trained: name -> the perturbations of the training env
VARIANTS: dict[str, Perturbations] = {"nominal": list, "robust": robust_training}
#: the conditions each variant is evaluated under: name -> the perturbations of the evaluation env
CONDITIONS: dict[str, Perturbations] = {"nominal": list, "pushes and delay": unseen_pushes_and_delay}


@dataclass(frozen=True)
class VelocityPPOConfig:
    """Hyper-parameters of a run (``frames_per_batch = num_envs * rollout_steps``)."""

    num_envs: int = 64
    rollout_steps: int = 32
    total_frames: int = 500_000
    epochs: int = 5
    minibatch_size: int = 512
    learning_rate: float = 1e-3
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    critic_coeff: float = 0.5
    max_grad_norm: float = 0.5
    hidden: int = 128
    initial_action_std: float = 0.5
    action_scale: float = 0.5
    mujoco_threads: int = 2
    curriculum_frames: int = 200_000
    eval_every: int = 100_000
    eval_envs: int = 16
    eval_steps: int = 1000
    max_minutes: float = 10.0

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.rollout_steps


#: the config fields that are command-line flags (``--num-envs`` for ``num_envs``)
FLAGS = (
    "num_envs",
    "rollout_steps",
    "total_frames",
    "epochs",
    "minibatch_size",
    "learning_rate",
    "hidden",
    "initial_action_std",
    "action_scale",
    "curriculum_frames",
    "eval_every",
    "eval_envs",
    "eval_steps",
    "max_minutes",
)
HELP = {
    **PPO_CONFIG_HELP,
    "curriculum_frames": "frames over which the command range widens from 30%% to all of it",
    "initial_action_std": "the policy's initial standard deviation (before its tanh)",
    "action_scale": "joint targets: home + action_scale * action [rad], actions in [-1, 1]",
}

#: --quick: two batches of 4 envs x 25 steps, evaluations of 2 envs x 30 steps
QUICK = VelocityPPOConfig(
    num_envs=4,
    rollout_steps=25,
    total_frames=200,
    epochs=1,
    minibatch_size=100,
    curriculum_frames=200,
    eval_every=200,
    eval_envs=2,
    eval_steps=30,
)


def file_stem(seed: int | str) -> str:
    return f"velocity_tracking_seed{seed}"


def make_env(
    config: VelocityPPOConfig, num_envs: int, seed: int, perturbations: Sequence[Transform], curriculum: bool
) -> TransformedEnv:
    """The velocity-tracking env (no normalisation): with the command curriculum for training, the full range else."""
    return velocity_tracking_env(
        num_envs,
        seed=seed,
        max_steps=1000,
        action_scale=config.action_scale,
        max_action_delay=MAX_ACTION_DELAY,
        curriculum_frames=config.curriculum_frames if curriculum else 0,
        num_threads=config.mujoco_threads,
        perturbations=perturbations,
    )


def make_policy(env: TransformedEnv, hidden: int, initial_std: float = 0.5) -> tuple[ProbabilisticActor, ValueOperator]:
    """The actor (``TanhNormal`` on ``[-1, 1]`` per joint: targets within ``action_scale`` rad of home, as
    IsaacLab's unit-scale actions) and the critic; ``train_locomotion_ppo.py``'s networks otherwise.

    The env's action box is the control range mapped back through the action map (up to ±3.6 here): a policy
    spread over it at the start falls within a few steps and, with the regularisers' costs, learns that ending the
    episode early pays; within ±1 and with a smaller initial spread (``initial_std`` before the tanh) it stands,
    and the tracking terms pay for staying up.
    """
    n_obs = env.observation_spec["observation"].shape[-1]
    n_act = env.action_spec.shape[-1]
    actor_net = nn.Sequential(
        mlp(n_obs, n_act, hidden, 0.01),
        AddStateIndependentNormalScale(n_act, scale_lb=1e-8, init_value=math.log(initial_std)),
    )
    bound = torch.ones(n_act, dtype=env.action_spec.dtype)
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -bound, "high": bound, "tanh_loc": False},
        return_log_prob=True,
        default_interaction_type=ExplorationType.RANDOM,
    )
    critic = ValueOperator(mlp(n_obs, 1, hidden, 1.0), in_keys=["observation"])
    return actor, critic


def tracking_errors(data: TensorDictBase) -> dict[str, float]:
    """Mean planar velocity and yaw-rate errors over all frames of ``data``: the command the policy saw at ``t``
    against the base's velocity at ``t + 1`` (in its own frame, from the task state: true values)."""
    command = data["command"]
    velocity = data["next", "base_lin_vel"][..., :2]
    yaw_rate = data["next", "base_ang_vel"][..., 2]
    return {
        "lin_vel_error": (command[..., :2] - velocity).norm(dim=-1).mean().item(),
        "yaw_rate_error": (command[..., 2] - yaw_rate).abs().mean().item(),
    }


@torch.no_grad()
def evaluate(
    actor: Callable[[TensorDictBase], TensorDictBase],
    vecnorm: VecNormV2 | None,
    config: VelocityPPOConfig,
    perturbations: Sequence[Transform] = (),
) -> dict[str, float]:
    """The deterministic policy for ``eval_steps`` steps in ``eval_envs`` envs (full command range) under
    ``perturbations``: tracking errors, falls per episode, mean return and episode length. ``vecnorm``: the
    policy's observation normalisation (``None``: a policy that reads no observation, :func:`stand_still`)."""
    env = make_env(config, config.eval_envs, EVAL_SEED, perturbations, False)
    if vecnorm is not None:
        env = normalised(env, vecnorm.to_observation_norm())
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(config.eval_steps, actor, break_when_any_done=False)
    env.close()
    nxt = rollout["next"]
    ended = nxt["done"].squeeze(-1).clone()
    ended[:, -1] = True  # the episodes still running at the end count, cut there
    falls_by = {name: int(nxt["ended_by", name].squeeze(-1).sum()) for name in FALLS}
    falls = sum(falls_by.values())
    returns = nxt["episode_reward"].squeeze(-1)[ended]
    stats = episode_statistics(rollout)
    return {
        **tracking_errors(rollout),
        "falls_per_episode": falls / int(ended.sum()),
        **{f"falls/{name}": count for name, count in falls_by.items()},
        "return_mean": returns.mean().item(),
        "episodes": int(ended.sum()),
        "episode_length_mean": ended.numel() / int(ended.sum()),
        "failure_rate": stats.get("failure_rate"),
    }


class ZeroAction(nn.Module):
    """Zero joint offsets for every observation row: the joint targets at home."""

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return observation.new_zeros((*observation.shape[:-1], 12))


def stand_still() -> TensorDictModule:
    """The baseline policy: zero actions, the joint targets at home (it stands; its errors are the commands')."""
    return TensorDictModule(ZeroAction(), in_keys=["observation"], out_keys=["action"])


def train(
    config: VelocityPPOConfig, seed: int, perturbations: Sequence[Transform] = (), label: str = "nominal"
) -> tuple[dict[str, Any], torch.nn.Module, VecNormV2]:
    """Train one policy for ``config.total_frames`` frames (or ``config.max_minutes``) on the env with
    ``perturbations``; return the run record, the actor and its observation normalisation."""
    torch.manual_seed(seed)
    clock = RunClock(config)
    env = make_env(config, config.num_envs, seed, perturbations, True)
    vecnorm = VecNormV2(in_keys=["observation"], decay=1.0, eps=1e-2, reduce_batch_dims=True)
    env = normalised(env, vecnorm)
    actor, critic = make_policy(env, config.hidden, config.initial_action_std)
    learner = PPOLearner(env, actor, critic, config)
    record: dict[str, Any] = {"variant": label, "curve": [], "eval_curve": []}
    frames = 0
    bar = frame_bar(f"PPO velocity tracking ({label}) seed {seed}", clock.batches * config.frames_per_batch)
    for iteration, batch in enumerate(learner.collector, start=1):
        frames += batch.numel()
        returns = training_returns(batch, TERMS)
        losses = learner.update(batch, iteration)
        ended = batch["next", "done"].squeeze(-1)
        falls = sum(batch["next", "ended_by", name].squeeze(-1).sum() for name in FALLS)
        point = {
            "iteration": iteration,
            "frames": frames,
            "seconds": clock.seconds(),
            **returns,
            **{f"train_{key}": value for key, value in tracking_errors(batch).items()},
            "episodes": int(ended.sum()),
            "falls": int(falls),
            "command_high": batch["curriculum", "command/high"][:, -1].mean(0).tolist()
            if ("curriculum", "command/high") in batch.keys(True)
            else None,
            "loss_critic": losses["loss_critic"].item(),
            "load_1min": machine_info()["load_1min"],
        }
        record["curve"].append(point)
        done = clock.is_last(iteration)
        stats = clock.evaluation(frames, done, lambda: evaluate(actor, vecnorm, config))
        if stats is not None:
            record["eval_curve"].append({"iteration": iteration, "frames": frames, "seconds": clock.seconds(), **stats})
            bar.set_postfix(
                lin_err=f"{stats['lin_vel_error']:.2f}",
                yaw_err=f"{stats['yaw_rate_error']:.2f}",
                falls=f"{stats['falls_per_episode']:.2f}",
            )
        bar.update(batch.numel())
        if done:
            break
    bar.close()
    learner.collector.shutdown()
    record.update(clock.totals(frames))
    return record, actor, vecnorm


def run(config: VelocityPPOConfig, seed: int) -> dict[str, Any]:
    """Train every variant of :data:`VARIANTS` and evaluate each under every condition of :data:`CONDITIONS`, beside
    the baseline :func:`stand_still` (zero actions) under the same conditions."""
    start = time.perf_counter()
    record: dict[str, Any] = {
        "task": "velocity tracking, shipped quadruped",
        "method": "PPO",
        "config": asdict(config),
        "seed": seed,
        "eval_seed": EVAL_SEED,
        "machine_start": machine_info(),
        "variants": {},
        "results": {},
    }
    record["results"]["standing still"] = {
        condition: evaluate(stand_still(), None, config, make()) for condition, make in CONDITIONS.items()
    }
    for variant, perturbations in VARIANTS.items():
        trained, actor, vecnorm = train(config, seed, perturbations(), variant)
        record["variants"][variant] = trained
        record["results"][variant] = {
            condition: evaluate(actor, vecnorm, config, make()) for condition, make in CONDITIONS.items()
        }
    record.update(total_seconds=time.perf_counter() - start, machine_end=machine_info())
    return record


def table(record: dict[str, Any]) -> str:
    """The run as markdown: each variant's evaluations during training, then every variant under every condition."""
    config = record["config"]
    lines = [
        f"# PPO velocity tracking, seed {record['seed']}",
        "",
        f"{config['num_envs']} envs x {config['rollout_steps']} steps per batch; wall time "
        f"{duration(record['total_seconds'])} (1-min load {record['machine_start']['load_1min']:.2f} at start, "
        f"{record['machine_end']['load_1min']:.2f} at end); evaluation: {config['eval_envs']} envs x "
        f"{config['eval_steps']} steps from seed {record['eval_seed']}, full command range.",
        "",
    ]
    errors = "planar velocity error [m/s] | yaw-rate error [rad/s] | falls per episode | return |"
    header = f"| frames | wall time | {errors}"
    rule = "| ---: | ---: | ---: | ---: | ---: | ---: |"
    for variant, trained in record["variants"].items():
        lines += [
            f"## Training: {variant} ({trained['total_frames']:,} frames, {trained['frames_per_second']:.0f} frames/s)",
            "",
            header,
            rule,
        ]
        for point in trained["eval_curve"]:
            lines.append(
                f"| {point['frames']:,} | {duration(point['seconds'])} | {point['lin_vel_error']:.3f} | "
                f"{point['yaw_rate_error']:.3f} | {point['falls_per_episode']:.2f} | {point['return_mean']:.2f} |"
            )
        lines.append("")
    lines += [
        "## Evaluation under each condition",
        "",
        f"| trained | evaluated | {errors}",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for variant, conditions in record["results"].items():
        for condition, stats in conditions.items():
            lines.append(
                f"| {variant} | {condition} | {stats['lin_vel_error']:.3f} | {stats['yaw_rate_error']:.3f} | "
                f"{stats['falls_per_episode']:.2f} | {stats['return_mean']:.2f} |"
            )
    return "\n".join(lines) + "\n"


def plot(records: Sequence[dict[str, Any]], path: Path) -> Path | None:
    """Tracking errors, falls and returns of each variant's evaluations against frames, one line per variant and
    seed (a colour per variant, a line style per seed); None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None
    from matplotlib.ticker import EngFormatter

    keys = (
        ("lin_vel_error", "planar velocity error [m/s]"),
        ("yaw_rate_error", "yaw-rate error [rad/s]"),
        ("falls_per_episode", "falls per episode"),
        ("return_mean", "return"),
    )
    styles = ("-", "--", ":", "-.")
    colours = {variant: f"C{k}" for k, variant in enumerate(VARIANTS)}
    figure, axes = plt.subplots(1, len(keys), figsize=(16, 4))
    for k, record in enumerate(records):
        for variant, trained in record["variants"].items():
            frames = [point["frames"] for point in trained["eval_curve"]]
            for axis, (key, label) in zip(axes, keys, strict=True):
                axis.plot(
                    frames,
                    [point[key] for point in trained["eval_curve"]],
                    marker="o",
                    color=colours.get(variant),
                    linestyle=styles[k % len(styles)],
                    label=f"{variant}, seed {record['seed']}",
                )
                axis.set_ylabel(label)
    baseline = records[0]["results"]["standing still"]["nominal"]  # the same for every seed: fixed commands
    for axis, (key, _) in zip(axes, keys, strict=True):
        axis.axhline(baseline[key], color="grey", linestyle="--", linewidth=1, label="standing still (zero actions)")
    for axis in axes:
        axis.set_xlabel("env frames")
        axis.xaxis.set_major_formatter(EngFormatter())
        axis.grid(alpha=0.3)
        axis.legend(fontsize="small")
    seconds = sum(record["total_seconds"] for record in records)
    scale, unit = time_unit(seconds)
    config = records[0]["config"]
    seeds = ", ".join(str(record["seed"]) for record in records)
    figure.suptitle(
        f"PPO velocity tracking, shipped quadruped, seed{'s' if len(records) > 1 else ''} {seeds} "
        f"({config['num_envs']} envs, {seconds / scale:.1f} {unit} in all)"
    )
    return save_figure(figure, path)


def summary(records: Sequence[dict[str, Any]]) -> str:
    """The runs of several seeds as markdown: the frames and wall times, then every variant under every condition
    with the mean over the seeds and each seed's value."""
    seeds = [record["seed"] for record in records]
    config = records[0]["config"]
    frames = {
        variant: sorted({record["variants"][variant]["total_frames"] for record in records}) for variant in VARIANTS
    }
    walls = ", ".join(f"seed {record['seed']} {duration(record['total_seconds'])}" for record in records)
    lines = [
        f"# PPO velocity tracking, seeds {', '.join(map(str, seeds))}",
        "",
        f"{config['num_envs']} envs x {config['rollout_steps']} steps per batch; frames per variant: "
        + "; ".join(f"{variant} {', '.join(f'{n:,}' for n in counts)}" for variant, counts in frames.items())
        + f". Wall time (both variants and every evaluation): {walls}. Evaluation: {config['eval_envs']} envs x "
        f"{config['eval_steps']} steps from seed {records[0]['eval_seed']}, full command range; each cell the mean "
        "over the seeds, then each seed's value.",
        "",
        "| trained | evaluated | planar velocity error [m/s] | yaw-rate error [rad/s] | falls per episode | return |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    metrics = (("lin_vel_error", 3), ("yaw_rate_error", 3), ("falls_per_episode", 2), ("return_mean", 2))
    for variant, conditions in records[0]["results"].items():
        for condition in conditions:
            cells = []
            for key, digits in metrics:
                values = [record["results"][variant][condition][key] for record in records]
                each = " / ".join(f"{value:.{digits}f}" for value in values)
                mean = sum(values) / len(values)
                cells.append(f"**{mean:.{digits}f}** ({each})" if len(values) > 1 else f"{mean:.{digits}f}")
            lines.append(f"| {variant} | {condition} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSON, the tables and the PNG")
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0],
        help="seeds of the envs, networks and sampling, one after the other",
    )
    defaults = VelocityPPOConfig()
    config_arguments(parser, defaults, HELP, FLAGS)
    args = parser.parse_args()
    config = config_from_args(parser, args, defaults, QUICK)
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    records = []
    for seed in args.seeds:
        record = run(config, seed)
        records.append(record)
        stem = args.output / file_stem(seed)
        json_path = stem.with_suffix(".json")
        json_path.write_text(json.dumps(record, indent=2))
        stem.with_suffix(".md").write_text(table(record))
        for variant, trained in record["variants"].items():
            first, last = trained["eval_curve"][0], trained["eval_curve"][-1]
            print(
                f"{variant}, seed {seed}: {trained['total_frames']} frames in {duration(trained['total_seconds'])} "
                f"({trained['frames_per_second']:.0f} frames/s); planar velocity error {first['lin_vel_error']:.3f} "
                f"-> {last['lin_vel_error']:.3f} m/s, yaw-rate error {first['yaw_rate_error']:.3f} -> "
                f"{last['yaw_rate_error']:.3f} rad/s, falls per episode {first['falls_per_episode']:.2f} -> "
                f"{last['falls_per_episode']:.2f}"
            )
        print(f"wrote {json_path} and {stem.with_suffix('.md')}")
        png = plot([record], stem.with_suffix(".png"))
        if png is not None:
            print(f"wrote {png}")
    if len(records) > 1:
        stem = args.output / file_stem("s" + "-".join(map(str, args.seeds)))
        text = summary(records)
        stem.with_suffix(".md").write_text(text)
        print(text)
        print(f"wrote {stem.with_suffix('.md')}")
        png = plot(records, stem.with_suffix(".png"))
        if png is not None:
            print(f"wrote {png}")


if __name__ == "__main__":
    from _cli import add_output_argument, config_arguments, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
