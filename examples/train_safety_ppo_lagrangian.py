"""PPO-Lagrangian against PPO on the Safety HalfCheetah velocity preset (cost limit 25 per 1000-step episode).

What it shows: :func:`~torchtasks.envs.locomotion.safety_velocity_env` (Gymnasium v5's HalfCheetah
reward and Safety-Gymnasium v1's velocity cost, ``cost = 1`` on every step with ``x_velocity >
3.2096``, as the constraint ``"velocity"`` of a :class:`~torchtasks.tasks.ConstrainedTask`) trained
with TorchRL's PPO pieces and a Lagrange multiplier, as OmniSafe's PPOLag:

- the ``TaskTransform`` writes the step cost ``("next", "task_cost", "velocity")`` and ``RewardSum``
  sums it into the episode cost ``("next", "task_cost", "episode_velocity")``;
- a **cost critic** (its own MLP) and a second ``GAE`` on the cost give the cost advantage ``A_c``;
  the reward advantage ``A_r`` comes from the reward critic and ``GAE`` as in
  ``train_locomotion_ppo.py``. The policy's advantage is OmniSafe's ``(Â_r − λ Ã_c) / (1 + λ)``
  (``Â_r`` standardised, ``Ã_c`` centred), fed to ``ClipPPOLoss`` (no further normalisation);
- the multiplier ``λ ≥ 0`` is a buffer of :class:`LagrangeMultiplier` (an ``nn.Module``: λ and its
  Adam moments are in its ``state_dict``), updated once per batch in which episodes ended, before
  the policy update, from the mean cost ``J_c`` of those episodes: one Adam step on the loss
  ``−λ (J_c − limit)`` then ``λ ← max(0, λ)`` (OmniSafe's ``Lagrange``: init 0.001, Adam).
- ``--variants ppo``: the same code with λ fixed at 0 (its cost critic is trained but unused), so the
  unconstrained run logs its episode costs too.

Batch layout: 16 envs × 128 steps (2048 frames per batch, as ``train_locomotion_ppo.py``'s 64 × 32).
All envs start together and HalfCheetah never terminates, so episodes end together every
1000 × 16 = 16,000 frames: λ is updated 62 times in 1M frames, each time from 16 whole episodes
(their exact costs, no estimate). OmniSafe's 1e6-step set-up (2048 steps per epoch) updates λ every
2048 frames with Adam's lr 0.035; λ's default lr here, 0.25 ≈ 0.035 × 16,000 / 2048, lets λ move
about as far per frame. Everything else (``VecNormV2`` on the observations, ``ReturnScaler`` on the
rewards, the networks, ``ClipPPOLoss``, Adam 3e-4 annealed, 10 epochs of minibatches of 128) is
``train_locomotion_ppo.py``'s, imported from there. One torch thread; MuJoCo on ``--mujoco-threads``.

Logged per batch: the mean return and episode cost of the training episodes that ended (RewardSum's
sums at their last frame), the fraction of them above the limit, λ, the losses. Every
``eval_every`` frames and at the end: a deterministic evaluation (one 1000-step episode in each of
``eval_envs`` envs from fixed initial states), ``episode_statistics(..., cost_limits={"velocity":
limit})`` of it (``return_mean``, ``cost_mean/velocity``, ``cost_violation_rate/velocity``).

Outputs in ``--output`` (default ``runs/train_safety_ppo_lagrangian``): ``<variant>_seed<N>.json``
per run and ``safety_ppo_lagrangian_curve.png`` (return, episode cost with the limit drawn, and λ
against frames, every run's JSON in the directory; needs matplotlib).

Run: ``python examples/train_safety_ppo_lagrangian.py [--variants lagrangian ppo] [--seeds 0 1 2]
[--total-frames N] [--quick] [--plot-only]`` (runs one after the other; ``--quick``: a few seconds,
every code path, for the tests; ``--plot-only``: re-plot the JSONs already in ``--output``).
Measured results: ``docs/constraints_results.md``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the other examples' modules

import torch
from _cli import duration, frame_bar
from _ppo_common import PPO_CONFIG_HELP, machine_info, ppo_update, pyplot, save_figure
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import ExplorationType, TransformedEnv, VecNormV2, set_exploration_type
from torchrl.modules import ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from train_locomotion_ppo import (
    GAE_NEXT_KEYS,
    ReturnScaler,
    clip_ppo_loss,
    make_policy,
    mlp,
    normalised,
    training_returns,
)

from torchtasks.envs.locomotion import MAX_EPISODE_STEPS, safety_velocity_env
from torchtasks.stats import episode_statistics

ENV_ID = "HalfCheetah-v5"
COST = "velocity"  # the preset's constraint
EPISODE_COST_KEY = ("next", "task_cost", f"episode_{COST}")  # RewardSum's sum of ("next", "task_cost", COST)
EVAL_SEED = 12345
DEFAULT_OUTPUT = Path("runs/train_safety_ppo_lagrangian")
PLOT_NAME = "safety_ppo_lagrangian_curve.png"
VARIANTS = ("lagrangian", "ppo")
LABELS = {"lagrangian": "PPO-Lagrangian", "ppo": "PPO (λ = 0)"}


@dataclass(frozen=True)
class SafetyPPOConfig:
    """Hyper-parameters of a run (``frames_per_batch = num_envs * rollout_steps``)."""

    num_envs: int = 16
    rollout_steps: int = 128
    total_frames: int = 1_000_000
    epochs: int = 10
    minibatch_size: int = 128
    learning_rate: float = 3e-4
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    critic_coeff: float = 0.5
    max_grad_norm: float = 0.5
    hidden: int = 64
    cost_limit: float = 25.0
    lambda_init: float = 0.001
    lambda_lr: float = 0.25
    mujoco_threads: int = 1
    eval_every: int = 250_000
    eval_envs: int = 8
    max_minutes: float = 40.0

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.rollout_steps


#: the ``--help`` text of every field (each is a flag: ``--num-envs`` for ``num_envs``)
CONFIG_HELP = {
    **PPO_CONFIG_HELP,
    "gamma": "discount γ of both GAEs",
    "lmbda": "GAE's λ, for the reward and the cost",
    "critic_coeff": "weight of the critic losses",
    "cost_limit": "limit on the episode cost of the velocity constraint",
    "lambda_init": "the multiplier's initial λ",
    "lambda_lr": "Adam's learning rate for λ",
}

#: --quick: two batches of 4 envs x 500 steps, so that the episodes end (and λ moves) in the second one
QUICK = SafetyPPOConfig(
    num_envs=4, rollout_steps=500, total_frames=4000, epochs=1, minibatch_size=1000, eval_every=4000, eval_envs=2
)


class LagrangeMultiplier(nn.Module):
    """λ ≥ 0 as a buffer, moved by Adam on ``−λ (J_c − limit)`` (OmniSafe's ``Lagrange``), then projected on λ ≥ 0.

    λ, Adam's two moments and its step count are buffers, so they are in the ``state_dict`` (a
    checkpoint resumes the multiplier). ``lr = 0`` keeps λ at its initial value (plain PPO with λ = 0).

    Example:
        >>> multiplier = LagrangeMultiplier(limit=25.0, init=0.0, lr=0.1)
        >>> # one episode cost above the limit, then six below: Adam's momentum carries λ up for three more updates
        >>> [round(multiplier.update(cost), 3) for cost in (125.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)]
        [0.1, 0.147, 0.167, 0.17, 0.16, 0.14, 0.112]
        >>> sorted(multiplier.state_dict())
        ['exp_avg', 'exp_avg_sq', 'steps', 'value']
    """

    def __init__(self, limit: float, init: float, lr: float, betas: tuple[float, float] = (0.9, 0.999)) -> None:
        super().__init__()
        self.limit, self.lr, self.betas, self.eps = limit, lr, betas, 1e-8
        self.register_buffer("value", torch.tensor(max(init, 0.0), dtype=torch.float64))
        self.register_buffer("exp_avg", torch.zeros((), dtype=torch.float64))
        self.register_buffer("exp_avg_sq", torch.zeros((), dtype=torch.float64))
        self.register_buffer("steps", torch.zeros((), dtype=torch.int64))

    @torch.no_grad()
    def update(self, episode_cost: float) -> float:
        """One Adam step from the mean episode cost ``J_c``; return the new λ."""
        if self.lr == 0.0:
            return self.value.item()
        grad = -(episode_cost - self.limit)  # d/dλ of the loss −λ (J_c − limit)
        beta1, beta2 = self.betas
        self.steps += 1
        self.exp_avg.mul_(beta1).add_((1 - beta1) * grad)
        self.exp_avg_sq.mul_(beta2).add_((1 - beta2) * grad * grad)
        step = self.steps.item()
        mean = self.exp_avg / (1 - beta1**step)
        rms = (self.exp_avg_sq / (1 - beta2**step)).sqrt()
        self.value.sub_(self.lr * mean / (rms + self.eps)).clamp_(min=0.0)
        return self.value.item()


class LagrangianPPOLoss(nn.Module):
    """``ClipPPOLoss`` (actor and reward critic) plus the L2 loss of the cost critic on its GAE targets.

    The cost critic's loss is added to ``loss_critic`` (so ``ppo_update`` back-propagates it) and
    reported alone as ``loss_cost_critic``.
    """

    def __init__(self, ppo_loss: ClipPPOLoss, cost_critic: ValueOperator, critic_coeff: float) -> None:
        super().__init__()
        self.ppo_loss, self.cost_critic, self.critic_coeff = ppo_loss, cost_critic, critic_coeff

    def forward(self, data: TensorDictBase) -> TensorDictBase:
        losses = self.ppo_loss(data)
        value = self.cost_critic(data.select("observation"))["cost_value"]
        cost_loss = self.critic_coeff * (value - data["cost_value_target"]).pow(2).mean()
        losses["loss_critic"] = losses["loss_critic"] + cost_loss
        losses["loss_cost_critic"] = cost_loss.detach()
        return losses


def make_env(config: SafetyPPOConfig, num_envs: int, seed: int) -> TransformedEnv:
    """The Safety HalfCheetah velocity preset (``cost_limit`` recorded in its task), not yet normalised."""
    return safety_velocity_env(
        ENV_ID, num_envs=num_envs, seed=seed, num_threads=config.mujoco_threads, cost_limit=config.cost_limit
    )


@torch.no_grad()
def evaluate(actor: nn.Module, config: SafetyPPOConfig, vecnorm: VecNormV2) -> dict[str, float]:
    """One deterministic 1000-step episode in each of ``eval_envs`` envs; ``episode_statistics`` with the limit."""
    env = normalised(make_env(config, config.eval_envs, EVAL_SEED), vecnorm.to_observation_norm())
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(MAX_EPISODE_STEPS, actor, break_when_any_done=False)
    env.close()
    stats = episode_statistics(rollout, cost_limits={COST: config.cost_limit})
    return {key: value for key, value in stats.items() if not key.endswith(("/step", "/final"))}


def training_costs(batch: TensorDictBase, limit: float) -> dict[str, float | None]:
    """Mean episode cost of the training episodes that ended in ``batch`` and the fraction of them above ``limit``."""
    done = batch["next", "done"]
    if not bool(done.any()):
        return {"train_cost": None, "train_violation_rate": None}
    costs = batch[EPISODE_COST_KEY][done]
    return {"train_cost": costs.mean().item(), "train_violation_rate": (costs > limit).double().mean().item()}


def combined_advantage(data: TensorDictBase, lam: float) -> torch.Tensor:
    """OmniSafe's PPOLag advantage ``(Â_r − λ Ã_c) / (1 + λ)``: ``Â_r`` standardised, ``Ã_c`` centred."""
    reward_adv, cost_adv = data["advantage"], data["cost_advantage"]
    reward_adv = (reward_adv - reward_adv.mean()) / (reward_adv.std() + 1e-8)
    cost_adv = cost_adv - cost_adv.mean()
    return (reward_adv - lam * cost_adv) / (1.0 + lam)


def train(config: SafetyPPOConfig, variant: str, seed: int) -> dict[str, Any]:
    """Train one run for ``config.total_frames`` frames (or ``config.max_minutes``); return its record."""
    torch.manual_seed(seed)
    start = time.perf_counter()
    vecnorm = VecNormV2(in_keys=["observation"], decay=1.0, eps=1e-2, reduce_batch_dims=True)
    env = normalised(make_env(config, config.num_envs, seed), vecnorm)
    actor, critic = make_policy(env, config.hidden)
    n_obs = env.observation_spec["observation"].shape[-1]
    cost_critic = ValueOperator(mlp(n_obs, 1, config.hidden, 1.0), in_keys=["observation"], out_keys=["cost_value"])
    log_std = next(module for module in actor.modules() if isinstance(module, AddStateIndependentNormalScale))
    reward_gae = GAE(gamma=config.gamma, lmbda=config.lmbda, value_network=critic, average_gae=False)
    cost_gae = GAE(gamma=config.gamma, lmbda=config.lmbda, value_network=cost_critic, average_gae=False)
    cost_gae.set_keys(reward="cost", advantage="cost_advantage", value_target="cost_value_target", value="cost_value")
    # the combined advantage is already normalised
    ppo_loss = clip_ppo_loss(actor, critic, config, normalize_advantage=False)
    loss_module = LagrangianPPOLoss(ppo_loss, cost_critic, config.critic_coeff)
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=config.learning_rate, eps=1e-5)
    lagrangian = variant == "lagrangian"
    multiplier = LagrangeMultiplier(
        config.cost_limit, config.lambda_init if lagrangian else 0.0, config.lambda_lr if lagrangian else 0.0
    )
    collector = Collector(
        env, actor, frames_per_batch=config.frames_per_batch, total_frames=-1, auto_register_policy_transforms=False
    )
    scaler = ReturnScaler(config.num_envs, config.gamma)
    iterations = math.ceil(config.total_frames / config.frames_per_batch)
    record: dict[str, Any] = {
        "env_id": ENV_ID,
        "preset": f"safety_velocity_env({ENV_ID!r}, cost_limit={config.cost_limit})",
        "variant": variant,
        "method": LABELS[variant],
        "config": asdict(config),
        "seed": seed,
        "machine_start": machine_info(),
        "curve": [],
        "eval_curve": [],
    }
    deadline = start + 60.0 * config.max_minutes
    frames, next_eval, last_train, last_eval = 0, config.eval_every, None, None
    bar = frame_bar(f"{LABELS[variant]} seed {seed}", iterations * config.frames_per_batch)  # whole batches
    for iteration, batch in enumerate(collector, start=1):
        frames += batch.numel()
        returns = training_returns(batch)
        costs = training_costs(batch, config.cost_limit)
        if costs["train_cost"] is not None:  # λ first, from the episodes that ended, then the policy (OmniSafe)
            multiplier.update(costs["train_cost"])
        lam = multiplier.value.item()
        for group in optimizer.param_groups:
            group["lr"] = config.learning_rate * (1.0 - (iteration - 1) / iterations)
        data = batch.select("observation", "action", "action_log_prob", *GAE_NEXT_KEYS)
        reward = scaler(batch["next", "reward"].squeeze(-1), batch["next", "done"].squeeze(-1))
        data["next", "reward"] = reward.unsqueeze(-1)
        data["next", "cost"] = batch["next", "task_cost", COST].float()
        with torch.no_grad():
            reward_gae(data)
            cost_gae(data)
            data["advantage"] = combined_advantage(data, lam)
        flat = data.exclude("next").reshape(-1)
        losses = ppo_update(
            loss_module,
            optimizer,
            flat,
            epochs=config.epochs,
            minibatch_size=config.minibatch_size,
            max_grad_norm=config.max_grad_norm,
        )
        collector.update_policy_weights_()
        point = {
            "iteration": iteration,
            "frames": frames,
            "seconds": time.perf_counter() - start,
            **returns,
            **costs,
            "lambda": lam,
            "loss_critic": losses["loss_critic"].item(),
            "loss_cost_critic": losses["loss_cost_critic"].item(),
            "clip_fraction": losses["clip_fraction"].item(),
            "action_scale": log_std.state_independent_scale.exp().mean().item(),
            "load_1min": machine_info()["load_1min"],
        }
        record["curve"].append(point)
        if costs["train_cost"] is not None:
            last_train = point
        done = iteration >= iterations or time.perf_counter() > deadline
        if frames >= next_eval or done:
            last_eval = {"iteration": iteration, "frames": frames, **evaluate(actor, config, vecnorm)}
            record["eval_curve"].append(last_eval)
            next_eval += config.eval_every
        postfix: dict[str, Any] = {"λ": f"{lam:.3f}"}
        if last_train is not None:
            postfix["return"] = f"{last_train['train_return']:.0f}"
            postfix["cost"] = f"{last_train['train_cost']:.0f}"
        bar.set_postfix(postfix)
        bar.update(batch.numel())
        if done:
            break
    bar.close()
    collector.shutdown()
    total_seconds = time.perf_counter() - start
    record.update(
        total_frames=frames,
        total_seconds=total_seconds,
        frames_per_second=frames / total_seconds,
        stopped_by_time_limit=frames < iterations * config.frames_per_batch,
        final_train_frames=None if last_train is None else last_train["frames"],
        final_train_return=None if last_train is None else last_train["train_return"],
        final_train_cost=None if last_train is None else last_train["train_cost"],
        final_train_violation_rate=None if last_train is None else last_train["train_violation_rate"],
        final_eval_return=last_eval["return_mean"],
        final_eval_cost=last_eval[f"cost_mean/{COST}"],
        final_eval_violation_rate=last_eval[f"cost_violation_rate/{COST}"],
        final_lambda=multiplier.value.item(),
        multiplier_state={key: value.item() for key, value in multiplier.state_dict().items()},
        machine_end=machine_info(),
    )
    return record


def plot(records: list[dict[str, Any]], path: Path) -> Path | None:
    """Training return, episode cost (limit drawn) and λ of every run against frames; None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None
    from matplotlib.ticker import EngFormatter

    figure, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    styles = ("-", "--", ":", "-.")
    for record in sorted(records, key=lambda record: (VARIANTS.index(record["variant"]), record["seed"])):
        color = f"C{VARIANTS.index(record['variant'])}"
        seed_index = sorted({r["seed"] for r in records if r["variant"] == record["variant"]}).index(record["seed"])
        style = styles[seed_index % len(styles)]
        ended = [point for point in record["curve"] if point["train_cost"] is not None]
        label = f"{record['method']}, seed {record['seed']}"
        x = [point["frames"] for point in ended]
        axes[0].plot(x, [point["train_return"] for point in ended], color=color, linestyle=style, label=label)
        axes[1].plot(x, [point["train_cost"] for point in ended], color=color, linestyle=style, label=label)
        curve = record["curve"]
        axes[2].plot([p["frames"] for p in curve], [p["lambda"] for p in curve], color=color, linestyle=style)
    limit = records[0]["config"]["cost_limit"]
    axes[1].axhline(limit, color="black", linewidth=1.2, label=f"cost limit {limit:g}")
    axes[0].set_ylabel("mean return of the training episodes")
    axes[1].set_ylabel("mean episode cost of the training episodes")
    axes[1].set_yscale("symlog", linthresh=10.0)  # linear up to 10, logarithmic above: the limit and PPO's costs
    top = max(max(p["train_cost"] for p in r["curve"] if p["train_cost"] is not None) for r in records)
    axes[1].set_ylim(0.0, 1.5 * max(top, 2 * limit))
    ticks = [tick for tick in (0, 5, 10, 25, 50, 100, 250, 500, 1000) if tick <= 1.5 * max(top, 2 * limit)]
    axes[1].set_yticks(ticks, [str(tick) for tick in ticks])
    axes[2].set_ylabel("Lagrange multiplier λ")
    for axis in axes:
        axis.set_xlabel("env frames")
        axis.xaxis.set_major_formatter(EngFormatter())
        axis.grid(alpha=0.3)
    axes[1].legend(fontsize="small")
    config = records[0]["config"]
    figure.suptitle(
        f"Safety {ENV_ID} velocity preset (cost 1 when x_velocity > 3.2096, limit {limit:g} per 1000-step episode); "
        f"{config['num_envs']} envs x {config['rollout_steps']} steps per batch"
    )
    return save_figure(figure, path)


def file_name(variant: str, seed: int | str) -> str:
    return f"{variant}_seed{seed}.json"


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory of the outputs")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds, trained one after the other")
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=VARIANTS,
        default=list(VARIANTS),
        metavar="NAME",
        help="lagrangian and/or ppo (λ fixed at 0)",
    )
    parser.add_argument("--plot-only", action="store_true", help="train nothing: re-plot the JSONs in --output")
    defaults = SafetyPPOConfig()
    config_arguments(parser, defaults, CONFIG_HELP)
    args = parser.parse_args()
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    config = QUICK if args.quick else defaults
    overrides = {name: value for name, value in vars(args).items() if name in asdict(config) and value is not None}
    config = replace(config, **overrides)
    for variant in () if args.plot_only else args.variants:
        for seed in args.seeds:
            record = train(config, variant, seed)
            json_path = args.output / file_name(variant, seed)
            json_path.write_text(json.dumps(record, indent=2))
            r = record
            print(
                f"{r['method']} seed {seed}: {r['total_frames']} frames in {duration(r['total_seconds'])} "
                f"({r['frames_per_second']:.0f} frames/s); training episodes at {r['final_train_frames']} frames: "
                f"return {r['final_train_return']:.1f}, episode cost {r['final_train_cost']:.1f}, above the limit "
                f"{r['final_train_violation_rate']:.0%}; λ {r['final_lambda']:.3f}; deterministic evaluation: "
                f"return {r['final_eval_return']:.1f}, episode cost {r['final_eval_cost']:.1f}"
            )
            print(f"wrote {json_path}")
    records = [json.loads(path.read_text()) for path in sorted(args.output.glob("*_seed*.json"))]
    if not records:
        print(f"no run in {args.output}: nothing to plot")
        return
    png = plot(records, args.output / PLOT_NAME)
    if png is not None:
        print(f"wrote {png} ({len(records)} run{'' if len(records) == 1 else 's'})")


if __name__ == "__main__":
    from _cli import add_output_argument, config_arguments, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
