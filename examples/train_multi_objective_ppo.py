"""PPO with one critic per reward group on an MO-Gymnasium preset, swept over weight vectors: a front of objectives.

What it shows: :func:`~torchtasks.envs.multi_objective.multi_objective_env` (``mo-halfcheetah-v5`` by default:
Gymnasium v5's HalfCheetah with MO-Gymnasium's vector reward ``[x_velocity, −Σa²]``, written by the
``TaskTransform`` of a :class:`~torchtasks.tasks.RewardGroupsTask` as ``("next", "vector_reward")``, ``[*B, k]``)
trained with TorchRL's PPO pieces and **one critic per group**, once per weight vector ``w``:

- the critic is ``train_locomotion_ppo.py``'s MLP with ``k`` outputs, one value per group;
- TorchRL's ``GAE`` runs on the ``k`` groups at once (:func:`group_advantages`): its functional GAE takes a
  trailing feature dim when the done flags have it too, so ``done`` and ``terminated`` are expanded to ``k``
  columns; every group gets its own advantage ``A_i`` and value target;
- the policy's advantage is ``Σ_i w_i A_i`` (:func:`combined_advantage`), normalised **after** combining (by
  ``ClipPPOLoss``, per minibatch, as the single-critic example). GAE is linear in the rewards and values, so
  ``Σ_i w_i A_i`` is the GAE of the scalarised reward ``w·r`` with the scalarised critic ``w·V``: the policy
  follows the same gradient as a single-critic PPO on ``w·r`` would, and ``w`` means what it means in
  MO-Gymnasium's ``LinearReward`` (``w = [1, 0.1]`` is Gymnasium's HalfCheetah reward). Normalising each
  group's advantage first would weigh group ``i`` by ``w_i / std(A_i)``, a ratio that drifts with the batch;
- one clipped PPO policy loss on that advantage and one L2 value loss per group, summed
  (:class:`MultiCriticPPOLoss`; each group's loss is logged).

The rewards the critics learn are all divided by one scale, the running standard deviation of the discounted
scalarised return ``w·r`` (``train_locomotion_ppo.py``'s ``ReturnScaler``, as Gymnasium's ``NormalizeReward``),
so the combination ``Σ_i w_i A_i`` keeps its meaning. Everything else (``VecNormV2`` on the observations, the
networks, ``ClipPPOLoss`` without entropy bonus, Adam 3e-4 annealed, 10 epochs of minibatches of 128, batches of
64 envs × 32 steps, one torch thread) is ``train_locomotion_ppo.py``'s, imported from there.

Logged per batch: the training episodes' returns per group (RewardSum's ``episode_vector_reward`` at their last
frame), the scalar reward's return and each group's critic loss. Every ``eval_every`` frames and at the end: a
deterministic evaluation (one 1000-step episode in each of ``eval_envs`` envs from fixed initial states) whose
per-objective returns are ``episode_statistics(...)["group_return_mean/<group>"]``: the points of the front.

Outputs in ``--output`` (default ``runs/train_multi_objective_ppo``): ``mo_ppo_w<w>_seed<N>.json`` per run,
``front.json`` (the last evaluation of every run in the directory: weights, per-objective returns, ``w·J``) and
``front.png`` (objective 0 against objective 1, a labelled point per weight vector and seed; needs matplotlib).
A table of the front is printed at the end.

The sweep: by default the env's scalarisation weights (``MultiObjectiveRecord.weights``, those under which
MO-Gymnasium's ``LinearReward`` gives Gymnasium's reward) with every weight after the first times 0.5, 1, 5 and
20 (1 and 20 with ``--quick``): ``1,0.05 1,0.1 1,0.5 1,2`` for ``mo-halfcheetah-v5``, ``1,0,0.0005 ...`` for
``mo-hopper-v5``. A weight vector needs one weight per objective of the env; a wrong count is refused with a
one-line error before anything runs.

Run: ``python examples/train_multi_objective_ppo.py [--env-id mo-halfcheetah-v5] [--weights 1,0.05 1,0.1]
[--seeds 0] [--total-frames N] [--quick] [--plot-only]`` (runs one after the other; ``--quick``: a few seconds
per weight vector, every code path, for the tests; ``--plot-only``: rebuild the front from the JSONs in
``--output``). Measured results: ``docs/reward_groups.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the other examples' modules

import torch
from _cli import default_text, duration, frame_bar
from _ppo_common import PPO_CONFIG_HELP, machine_info, ppo_update, pyplot
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import ExplorationType, TransformedEnv, VecNormV2, set_exploration_type
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from train_locomotion_ppo import (
    FLAGS,
    GAE_NEXT_KEYS,
    LocomotionPPOConfig,
    Preset,
    ReturnScaler,
    make_env,
    make_eval_env,
    make_policy,
)

from torchtasks.stats import episode_statistics
from torchtasks.transforms import TaskTransform

ENV_ID = "mo-halfcheetah-v5"
#: the default sweep (:func:`sweep`): the env's scalarisation weights, every weight after the first times each
#: factor; for mo-halfcheetah-v5, whose weights [1, 0.1] give Gymnasium's reward (forward + 0.1 · (−Σa²)):
#: 1,0.05 1,0.1 1,0.5 1,2
SWEEP_FACTORS = (0.5, 1.0, 5.0, 20.0)
DEFAULT_OUTPUT = Path("runs/train_multi_objective_ppo")
FRONT_JSON = "front.json"
FRONT_PNG = "front.png"
VECTOR_REWARD = ("next", "vector_reward")  # the TaskTransform's groups, [*B, k]
EPISODE_VECTOR_REWARD = ("next", "episode_vector_reward")  # RewardSum's running sum of them
#: the per-group entries of the PPO batch: the critics' scaled rewards, and GAE's outputs
GROUP_REWARD, GROUP_ADVANTAGE, GROUP_VALUE_TARGET = "group_reward", "group_advantage", "group_value_target"
GROUP_DONE, GROUP_TERMINATED = "group_done", "group_terminated"  # done/terminated expanded to k columns


@dataclass(frozen=True)
class MultiObjectivePPOConfig(LocomotionPPOConfig):
    """``train_locomotion_ppo.py``'s hyper-parameters on an MO preset, with a frame budget for a sweep."""

    env_id: str = ENV_ID
    total_frames: int = 300_000
    eval_every: int = 150_000
    eval_envs: int = 8
    max_minutes: float = 12.0


CONFIG_HELP = {
    **PPO_CONFIG_HELP,
    "total_frames": "frames per weight vector, rounded up to whole batches",
    "critic_coeff": "weight of each group's critic loss",
    "max_minutes": "wall-clock limit per run in minutes",
}

#: --quick: two weight vectors, each two batches of 4 envs x 125 steps and a 250-step evaluation of 2 envs (the
#: episodes, 1000 steps long, do not end: the returns are those of the partial episodes)
QUICK = MultiObjectivePPOConfig(
    num_envs=4,
    rollout_steps=125,
    total_frames=1000,
    epochs=1,
    minibatch_size=250,
    eval_every=1000,
    eval_envs=2,
    eval_steps=250,
)
QUICK_FACTORS = (1.0, 20.0)


def weight_vector(text: str) -> tuple[float, ...]:
    """Parse one ``--weights`` item, comma-separated finite numbers, not all zero.

    Example:
        >>> weight_vector("1,0.05"), weight_vector("1, -2")
        ((1.0, 0.05), (1.0, -2.0))
    """
    try:
        weights = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a weight vector is comma-separated numbers (1,0.1), got {text!r}") from None
    if not all(math.isfinite(weight) for weight in weights) or not any(weights):
        raise argparse.ArgumentTypeError(f"a weight vector needs finite weights, not all zero, got {text!r}")
    return weights


def sweep(weights: Sequence[float], factors: Sequence[float]) -> tuple[tuple[float, ...], ...]:
    """The weight vectors of a sweep: ``weights`` with every weight after the first times each factor, in order,
    repeats dropped (an env whose weights after the first are all 0 gets one vector).

    Example: ``sweep((1.0, 0.1), (0.5, 1.0, 5.0, 20.0))`` is ``((1.0, 0.05), (1.0, 0.1), (1.0, 0.5), (1.0, 2.0))``.
    """
    vectors = (tuple([weights[0], *(weight * factor for weight in weights[1:])]) for factor in factors)
    return tuple(dict.fromkeys(vectors))


def weight_sweep(
    parser: argparse.ArgumentParser, args: argparse.Namespace, env_id: str
) -> tuple[tuple[float, ...], ...]:
    """The weight vectors to train for ``env_id``: ``--weights``, or the sweep of the env's record (:func:`sweep`).

    Checked against the env's record before anything runs: an unknown env id or a weight vector whose length is
    not the env's number of objectives ends the program with a one-line error (``parser.error``: exit status 2).
    """
    from torchtasks.envs.multi_objective import multi_objective_record

    try:
        record = multi_objective_record(env_id)
    except ValueError as error:
        parser.error(f"--env-id: {error}")
    names = record.objective_names
    for weights in args.weights or ():
        if len(weights) != len(names):
            parser.error(
                f"--weights: {env_id} has {len(names)} objectives ({', '.join(names)}), so a weight vector needs "
                f"{len(names)} weights; got {shown_weights(weights)}"
            )
    if args.weights:
        return tuple(args.weights)
    return sweep(record.weights, QUICK_FACTORS if args.quick else SWEEP_FACTORS)


def shown_weights(weights: Sequence[float]) -> str:
    """``(1.0, 0.05)`` -> ``"1,0.05"`` (the ``--weights`` spelling, also in file names)."""
    return ",".join(f"{weight:g}" for weight in weights)


def group_names(env: TransformedEnv) -> tuple[str, ...]:
    """The reward groups of ``env``'s task, in the order of the columns of ``("next", "vector_reward")``."""
    tasks = [transform.task for transform in env.transform if isinstance(transform, TaskTransform)]
    if len(tasks) != 1 or not tasks[0].group_names:
        raise ValueError(f"the env needs one TaskTransform whose task has reward groups, got {len(tasks)} tasks")
    return tasks[0].group_names


def make_group_gae(critic: ValueOperator, gamma: float, lmbda: float) -> GAE:
    """TorchRL's ``GAE`` on the critic's ``k`` values, reading and writing the group entries (see
    :func:`group_advantages`)."""
    gae = GAE(gamma=gamma, lmbda=lmbda, value_network=critic, average_gae=False)
    gae.set_keys(
        reward=GROUP_REWARD,
        advantage=GROUP_ADVANTAGE,
        value_target=GROUP_VALUE_TARGET,
        done=GROUP_DONE,
        terminated=GROUP_TERMINATED,
    )
    return gae


@torch.no_grad()
def group_advantages(gae: GAE, data: TensorDictBase) -> TensorDictBase:
    """Write every group's GAE advantage and value target into ``data``, ``[*B, T, k]`` each.

    ``data``: a ``[*B, T]`` batch with ``"observation"``, ``("next", "observation")``, ``("next", "done")``,
    ``("next", "terminated")`` (``[*B, T, 1]``) and the groups' rewards ``("next", "group_reward")``
    (``[*B, T, k]``); ``gae``: :func:`make_group_gae` of a critic with ``k`` outputs. TorchRL's functional GAE
    handles a trailing dim of ``k`` when the done flags have it: they are expanded (no copy) to
    ``("next", "group_done")`` and ``("next", "group_terminated")``. Group ``i``'s advantage and target are
    those of a one-output critic trained on group ``i``'s reward alone.
    """
    nxt = data["next"]
    reward = nxt[GROUP_REWARD]
    if reward.dim() != data.batch_dims + 1:
        raise ValueError(
            f"group_advantages: ('next', {GROUP_REWARD!r}) must be [*B, T, k] for a [*B, T] batch "
            f"{list(data.batch_size)}, got {list(reward.shape)}"
        )
    shape = reward.shape
    nxt[GROUP_DONE] = nxt["done"].expand(shape)
    nxt[GROUP_TERMINATED] = nxt["terminated"].expand(shape)
    return gae(data)


def combined_advantage(advantages: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """``Σ_i w_i A_i``: the per-group advantages ``[..., k]`` weighted by ``weights`` ``[k]``, as ``[..., 1]``.

    Example:
        >>> combined_advantage(torch.tensor([[2.0, -1.0], [0.0, 4.0]]), torch.tensor([1.0, 0.5]))
        tensor([[1.5000],
                [2.0000]])
    """
    if weights.dim() != 1 or advantages.shape[-1:] != weights.shape:
        raise ValueError(
            f"combined_advantage: weights must be [k] for advantages [..., k], got weights {list(weights.shape)} "
            f"and advantages {list(advantages.shape)}"
        )
    return (advantages * weights).sum(-1, keepdim=True)


class MultiCriticPPOLoss(nn.Module):
    """``ClipPPOLoss`` of the actor on ``"advantage"`` plus one L2 value loss per group, summed.

    ``critic`` writes ``k`` values to ``"state_value"``; its targets are ``"group_value_target"`` (``[N, k]``,
    :func:`group_advantages`). Group ``i``'s loss is ``critic_coeff · mean_n (V_i(s_n) − target_{n,i})²``;
    ``loss_critic`` is their sum (``ppo_update`` back-propagates it) and ``loss_critic_groups`` the ``[k]``
    losses, detached. The advantage is normalised per minibatch (``ClipPPOLoss``'s ``normalize_advantage``).
    """

    def __init__(
        self, actor: ProbabilisticActor, critic: ValueOperator, *, clip_epsilon: float, critic_coeff: float
    ) -> None:
        super().__init__()
        self.policy_loss = ClipPPOLoss(
            actor, None, clip_epsilon=clip_epsilon, entropy_bonus=False, normalize_advantage=True
        )
        self.critic, self.critic_coeff = critic, critic_coeff

    def forward(self, data: TensorDictBase) -> TensorDictBase:
        losses = self.policy_loss(data)
        value = self.critic(data.select("observation"))["state_value"]
        per_group = self.critic_coeff * (value - data[GROUP_VALUE_TARGET]).pow(2).mean(0)
        losses["loss_critic"] = per_group.sum()
        losses["loss_critic_groups"] = per_group.detach()
        return losses


def training_returns(batch: TensorDictBase, groups: Sequence[str]) -> dict[str, float | None]:
    """Mean return and per-group returns of the training episodes that ended in ``batch`` (RewardSum's sums)."""
    nxt = batch["next"]
    done = nxt["done"].squeeze(-1)
    if not bool(done.any()):
        return {"train_return": None, **{f"train_return/{group}": None for group in groups}}
    per_group = batch[EPISODE_VECTOR_REWARD][done].double().mean(0).tolist()
    stats = {"train_return": nxt["episode_reward"][done].mean().item()}
    return stats | {f"train_return/{group}": value for group, value in zip(groups, per_group, strict=True)}


@torch.no_grad()
def evaluate(
    actor: nn.Module, config: MultiObjectivePPOConfig, vecnorm: VecNormV2, preset: Preset, groups: Sequence[str]
) -> dict[str, float]:
    """One deterministic episode (``eval_steps`` steps) in each of ``eval_envs`` envs; ``episode_statistics`` of it.

    ``group_return_mean/<group>``: the mean per-objective return of the complete episodes (of the partial ones
    when ``eval_steps`` ends them all early, from RewardSum's sums at the last step).
    """
    env = make_eval_env(config, vecnorm, preset=preset)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(config.eval_steps, actor, break_when_any_done=False)
    env.close()
    stats = episode_statistics(rollout)
    if not stats["complete_episodes"]:
        stats["return_mean"] = rollout["next", "episode_reward"][:, -1].mean().item()
        partial = rollout[EPISODE_VECTOR_REWARD][:, -1].double().mean(0).tolist()
        stats |= {f"group_return_mean/{group}": value for group, value in zip(groups, partial, strict=True)}
    return {key: value for key, value in stats.items() if not key.endswith(("/step", "/final"))}


def multi_objective_preset() -> Preset:
    """:func:`~torchtasks.envs.multi_objective.multi_objective_env`, imported when a run starts."""
    from torchtasks.envs.multi_objective import multi_objective_env

    return multi_objective_env


def train(
    config: MultiObjectivePPOConfig, weights: Sequence[float], seed: int, preset: Preset | None = None
) -> dict[str, Any]:
    """Train one weight vector for ``config.total_frames`` frames (or ``config.max_minutes``); return its record.

    ``preset``: the env factory (default :func:`multi_objective_preset`), called as ``train_locomotion_ppo``'s
    ``make_env`` calls it; its task must have ``len(weights)`` reward groups.
    """
    preset = multi_objective_preset() if preset is None else preset
    torch.manual_seed(seed)
    start = time.perf_counter()
    env, vecnorm = make_env(config, seed, preset=preset)
    groups = group_names(env)
    if len(weights) != len(groups):
        raise ValueError(
            f"--weights: {config.env_id} has {len(groups)} reward groups {list(groups)}, so a weight vector needs "
            f"{len(groups)} weights; got {shown_weights(weights)}"
        )
    w = torch.tensor(weights, dtype=torch.float32)
    actor, critic = make_policy(env, config.hidden, values=len(groups))
    log_std = next(module for module in actor.modules() if isinstance(module, AddStateIndependentNormalScale))
    gae = make_group_gae(critic, config.gamma, config.lmbda)
    loss_module = MultiCriticPPOLoss(actor, critic, clip_epsilon=config.clip_epsilon, critic_coeff=config.critic_coeff)
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=config.learning_rate, eps=1e-5)
    collector = Collector(
        env, actor, frames_per_batch=config.frames_per_batch, total_frames=-1, auto_register_policy_transforms=False
    )
    scaler = ReturnScaler(config.num_envs, config.gamma)
    iterations = math.ceil(config.total_frames / config.frames_per_batch)
    record: dict[str, Any] = {
        "env_id": config.env_id,
        "method": "PPO, one critic per group",
        "weights": list(weights),
        "groups": list(groups),
        "config": asdict(config),
        "seed": seed,
        "machine_start": machine_info(),
        "curve": [],
        "eval_curve": [],
    }
    deadline = start + 60.0 * config.max_minutes
    frames, next_eval, last_train, last_eval = 0, config.eval_every, None, None
    bar = frame_bar(f"w = {shown_weights(weights)} seed {seed}", iterations * config.frames_per_batch)
    for iteration, batch in enumerate(collector, start=1):
        frames += batch.numel()
        returns = training_returns(batch, groups)
        if config.anneal_lr:
            for group in optimizer.param_groups:
                group["lr"] = config.learning_rate * (1.0 - (iteration - 1) / iterations)
        data = batch.select("observation", "action", "action_log_prob", *GAE_NEXT_KEYS)
        vector = batch[VECTOR_REWARD].double()  # [envs, time, k]
        scaler.update((vector * w.double()).sum(-1), batch["next", "done"].squeeze(-1))  # the scale of w·r
        data["next", GROUP_REWARD] = scaler.scale(vector)
        group_advantages(gae, data)
        data["advantage"] = combined_advantage(data[GROUP_ADVANTAGE], w)
        losses = ppo_update(
            loss_module,
            optimizer,
            data.select("observation", "action", "action_log_prob", "advantage", GROUP_VALUE_TARGET).reshape(-1),
            epochs=config.epochs,
            minibatch_size=config.minibatch_size,
            max_grad_norm=config.max_grad_norm,
        )
        collector.update_policy_weights_()
        critic_losses = losses["loss_critic_groups"].tolist()
        point = {
            "iteration": iteration,
            "frames": frames,
            "seconds": time.perf_counter() - start,
            **returns,
            **{f"loss_critic/{group}": loss for group, loss in zip(groups, critic_losses, strict=True)},
            "clip_fraction": losses["clip_fraction"].item(),
            "action_scale": log_std.state_independent_scale.exp().mean().item(),
            "load_1min": machine_info()["load_1min"],
        }
        record["curve"].append(point)
        if returns["train_return"] is not None:
            last_train = point
        done = iteration >= iterations or time.perf_counter() > deadline
        if frames >= next_eval or done:
            stats = evaluate(actor, config, vecnorm, preset, groups)
            last_eval = {"iteration": iteration, "frames": frames, "seconds": time.perf_counter() - start, **stats}
            record["eval_curve"].append(last_eval)
            next_eval += config.eval_every
        if last_train is not None:
            bar.set_postfix({group: f"{last_train[f'train_return/{group}']:.0f}" for group in groups})
        bar.update(batch.numel())
        if done:
            break
    bar.close()
    collector.shutdown()
    env.close()
    total_seconds = time.perf_counter() - start
    final = [last_eval[f"group_return_mean/{group}"] for group in groups]
    record.update(
        total_frames=frames,
        total_seconds=total_seconds,
        frames_per_second=frames / total_seconds,
        stopped_by_time_limit=frames < iterations * config.frames_per_batch,
        final_train_frames=None if last_train is None else last_train["frames"],
        final_eval_returns=dict(zip(groups, final, strict=True)),
        final_eval_return=last_eval["return_mean"],
        final_eval_weighted_return=sum(weight * value for weight, value in zip(weights, final, strict=True)),
        machine_end=machine_info(),
    )
    return record


def front(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The front of ``records`` (runs of one env): per run, its weights, seed and last evaluation's returns.

    Also the evaluation's size, from the first record (``--plot-only`` over runs of other sizes keeps that one).
    """
    envs = sorted({(record["env_id"], tuple(record["groups"])) for record in records})
    if len(envs) != 1:
        raise ValueError(f"the runs must share one env and its groups to form a front, got {envs}")
    points = [
        {
            "weights": record["weights"],
            "seed": record["seed"],
            "returns": record["final_eval_returns"],
            "weighted_return": record["final_eval_weighted_return"],
            "scalar_return": record["final_eval_return"],
            "frames": record["total_frames"],
            "seconds": record["total_seconds"],
        }
        for record in sorted(records, key=lambda record: (record["weights"], record["seed"]))
    ]
    env_id, groups = envs[0]
    config = records[0]["config"]
    evaluation = {"eval_envs": config["eval_envs"], "eval_steps": config["eval_steps"]}
    return {"env_id": env_id, "groups": list(groups), **evaluation, "points": points}


def table(front_data: dict[str, Any]) -> str:
    """The front as a text table: one row per run (weights, seed, return per objective, ``w·J``, frames, time)."""
    groups = front_data["groups"]
    header = ["weights", "seed", *groups, "w·J", "frames", "time"]
    rows = [
        [
            shown_weights(point["weights"]),
            str(point["seed"]),
            *(f"{point['returns'][group]:,.1f}" for group in groups),
            f"{point['weighted_return']:,.1f}",
            f"{point['frames']:,}",
            duration(point["seconds"]),
        ]
        for point in front_data["points"]
    ]
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    lines = ["  ".join(cell.rjust(width) for cell, width in zip(row, widths, strict=True)) for row in (header, *rows)]
    return "\n".join(lines)


def plot(front_data: dict[str, Any], path: Path) -> Path | None:
    """Objective 0 against objective 1 of every run, one labelled marker per weight vector; None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None

    x_group, y_group = front_data["groups"][:2]
    markers = "osD^vP*X"
    figure, axis = plt.subplots(figsize=(7.5, 5.5))
    vectors = sorted({tuple(point["weights"]) for point in front_data["points"]})
    for index, weights in enumerate(vectors):
        points = [point for point in front_data["points"] if tuple(point["weights"]) == weights]
        x = [point["returns"][x_group] for point in points]
        y = [point["returns"][y_group] for point in points]
        label = f"w = ({', '.join(f'{weight:g}' for weight in weights)})"
        axis.scatter(x, y, s=70, marker=markers[index % len(markers)], color=f"C{index}", label=label, zorder=3)
        for point, px, py in zip(points, x, y, strict=True):
            text = label if len(points) == 1 else f"{label}, seed {point['seed']}"
            axis.annotate(text, (px, py), xytext=(7, 5), textcoords="offset points", fontsize="small")
    axis.set_xlabel(f"{x_group} return (objective 0)")
    axis.set_ylabel(f"{y_group} return (objective 1)")
    axis.grid(alpha=0.3)
    axis.legend(fontsize="small", loc="best")
    axis.margins(0.15)
    frames = sorted({point["frames"] for point in front_data["points"]})
    budget = f"{frames[0]:,} frames" if len(frames) == 1 else f"{frames[0]:,}–{frames[-1]:,} frames"
    axis.set_title(
        f"PPO with one critic per group on {front_data['env_id']}, {budget} per run\n"
        f"deterministic evaluation, {front_data['eval_envs']} envs x {front_data['eval_steps']} steps: "
        "mean episode returns",
        fontsize="medium",
    )
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def file_name(weights: Sequence[float] | str, seed: int | str) -> str:
    text = weights if isinstance(weights, str) else shown_weights(weights).replace(",", "_")
    return f"mo_ppo_w{text}_seed{seed}.json"


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory of the outputs")
    factors = ", ".join(f"{factor:g}" for factor in SWEEP_FACTORS)
    parser.add_argument(
        "--weights",
        type=weight_vector,
        nargs="+",
        metavar="W",
        help="weight vectors, one run each, one weight per objective of the env "
        + default_text(
            f"the scalarisation weights of the env, those after the first times {factors}: "
            + " ".join(map(shown_weights, sweep((1.0, 0.1), SWEEP_FACTORS)))
            + f" for {ENV_ID}",
            "times " + " and ".join(f"{factor:g}" for factor in QUICK_FACTORS) + " with --quick",
        ),
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds, trained one after the other")
    parser.add_argument("--plot-only", action="store_true", help="train nothing: rebuild the front from --output")
    defaults = MultiObjectivePPOConfig()
    parser.add_argument("--env-id", metavar="ID", help=f"the multi-objective preset {default_text(defaults.env_id)}")
    config_arguments(parser, defaults, CONFIG_HELP, FLAGS)
    args = parser.parse_args()
    config = QUICK if args.quick else defaults
    overrides = {name: value for name, value in vars(args).items() if name in asdict(config) and value is not None}
    config = replace(config, **overrides)
    vectors = weight_sweep(parser, args, config.env_id)  # refused here, before anything is written or built
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    for weights in () if args.plot_only else vectors:
        for seed in args.seeds:
            record = train(config, weights, seed)
            json_path = args.output / file_name(weights, seed)
            json_path.write_text(json.dumps(record, indent=2))
            returns = ", ".join(f"{group} {value:.1f}" for group, value in record["final_eval_returns"].items())
            print(
                f"w = {shown_weights(weights)} seed {seed}: {record['total_frames']} frames in "
                f"{duration(record['total_seconds'])} ({record['frames_per_second']:.0f} frames/s); deterministic "
                f"evaluation: {returns}, w·J {record['final_eval_weighted_return']:.1f}"
            )
            print(f"wrote {json_path}")
    records = [json.loads(path.read_text()) for path in sorted(args.output.glob(file_name("*", "*")))]
    if not records:
        print(f"no run in {args.output}: no front")
        return
    front_data = front(records)
    front_path = args.output / FRONT_JSON
    front_path.write_text(json.dumps(front_data, indent=2))
    print(f"wrote {front_path} ({len(records)} run{'' if len(records) == 1 else 's'})")
    png = plot(front_data, args.output / FRONT_PNG)
    if png is not None:
        print(f"wrote {png}")
    print(table(front_data))


if __name__ == "__main__":
    from _cli import add_output_argument, config_arguments, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
