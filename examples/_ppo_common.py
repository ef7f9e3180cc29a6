"""The PPO building blocks shared by the pendulum examples (not a script).

``train_swingup_ppo.py`` (PPO on the dense swing-up task) and ``potential_shaping.py`` (PPO on a
sparse success reward, with and without potential-based shaping) import from here: the batched
pendulum env with a torchtasks task (:func:`make_pendulum_env`), the networks (:func:`make_policy`),
the hyper-parameters (:class:`PPOConfig`), the deterministic evaluation from fixed initial states
(:func:`evaluate`), the TorchRL PPO loop (:func:`train`, its gradient steps in :func:`ppo_update`)
and the JSON/PNG output (:func:`save`). ``train_locomotion_ppo.py`` (PPO on MuJoCo HalfCheetah)
reuses :func:`ppo_update` and :func:`machine_info`; the MuJoCo PPO examples also take their flags' help
(:data:`PPO_CONFIG_HELP`), their config from the flags (:func:`config_from_args`) and the first and last steps of
their plots (:func:`pyplot`, :func:`save_figure`) from here. Which task the pendulums are trained and
evaluated on is the caller's choice: :func:`train` and :func:`evaluate` take env factories
``(num_envs, seed) -> env``. See ``train_swingup_ppo.py`` for the set-up and ``docs/training.md``
for the measured results.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from _cli import duration, frame_bar, time_unit
from tensordict import TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import Compose, ExplorationType, RewardSum, StepCounter, TransformedEnv, set_exploration_type
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from torchtasks._plotting import mark_short_series
from torchtasks.envs import PendulumEnv
from torchtasks.stats import episode_statistics
from torchtasks.tasks import Task
from torchtasks.transforms import TaskTransform

MAX_STEPS = 200  # episode length limit (StepCounter), 10 s
MAX_TORQUE = 2.0  # PendulumEnv's torque bound
MAX_SPEED = 8.0  # PendulumEnv's speed bound
EVAL_ENVS = 256
EVAL_SEED = 12345

#: ``(num_envs, seed) -> env``: builds the batched pendulums a run trains or evaluates on
EnvFactory = Callable[[int, int], TransformedEnv]


@dataclass(frozen=True)
class PPOConfig:
    """Hyper-parameters of a PPO run (``frames_per_batch = num_envs * rollout_steps``)."""

    num_envs: int = 256
    rollout_steps: int = 32
    epochs: int = 8
    minibatch_size: int = 1024
    learning_rate: float = 1e-3
    gamma: float = 0.98
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coeff: float = 1e-3
    critic_coeff: float = 0.5
    max_grad_norm: float = 1.0
    reward_scale: float = 0.01
    hidden: int = 64
    max_minutes: float = 10.0
    target: float = 0.8

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.rollout_steps


QUICK = PPOConfig(num_envs=32, rollout_steps=16, epochs=2, minibatch_size=256, max_minutes=0.5)
QUICK_ITERATIONS = 3


class PendulumFeatures(nn.Module):
    """Map the raw state ``[θ, θ̇]`` to ``[cos θ, sin θ, θ̇ / max_speed]`` (continuous in θ, of order 1).

    Example:
        >>> PendulumFeatures()(torch.tensor([[0.0, 4.0]]))
        tensor([[1.0000, 0.0000, 0.5000]])
    """

    def __init__(self, max_speed: float = MAX_SPEED) -> None:
        super().__init__()
        self.max_speed = max_speed

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        theta, speed = state[..., 0], state[..., 1]
        return torch.stack((torch.cos(theta), torch.sin(theta), speed / self.max_speed), dim=-1)


#: ``--help`` text of the PPO config fields the MuJoCo PPO examples share (each is a flag: ``--num-envs``)
PPO_CONFIG_HELP = {
    "num_envs": "envs stepped as one batch",
    "rollout_steps": "steps per env and batch",
    "total_frames": "frames to train for, rounded up to whole batches",
    "epochs": "PPO passes over each batch",
    "minibatch_size": "frames per PPO minibatch",
    "learning_rate": "Adam's learning rate, annealed linearly to 0",
    "gamma": "discount γ",
    "lmbda": "GAE's λ",
    "clip_epsilon": "PPO's clipping ε",
    "critic_coeff": "weight of the critic loss",
    "max_grad_norm": "gradient norm clipped to this",
    "hidden": "units per hidden layer",
    "mujoco_threads": "threads stepping MuJoCo",
    "eval_every": "frames between two deterministic evaluations",
    "eval_envs": "envs of each evaluation, one episode each",
    "eval_steps": "steps of each evaluation episode",
    "max_minutes": "wall-clock limit in minutes",
}


def config_problem(config: Any) -> str | None:
    """What is wrong with a PPO config dataclass as the flags set it (``"--num-envs must be at least 1, got 0"``), or
    None: every integer field is a count (at least 1), every float field a positive finite number.

    The MuJoCo PPO examples call it after parsing, before anything is built, and hand its message to
    ``parser.error``: a wrong flag is one line, not a traceback.

    Example:
        >>> config_problem(PPOConfig()) is None, config_problem(PPOConfig(num_envs=0))
        (True, '--num-envs must be at least 1, got 0')
        >>> config_problem(PPOConfig(learning_rate=float("nan")))
        '--learning-rate must be a positive number, got nan'
    """
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        flag = f"--{field.name.replace('_', '-')}"
        if isinstance(value, bool):
            continue
        if isinstance(value, int) and value < 1:
            return f"{flag} must be at least 1, got {value}"
        if isinstance(value, float) and not (math.isfinite(value) and value > 0):
            return f"{flag} must be a positive number, got {value}"
    return None


def config_from_args(
    parser: argparse.ArgumentParser, args: argparse.Namespace, defaults: Any, quick: Any, **fixed: Any
) -> Any:
    """The config a run uses: ``quick`` with ``--quick``, else ``defaults``, with every config flag given (not None)
    and the ``fixed`` fields; a config that :func:`config_problem` refuses is ``parser.error`` (exit status 2).

    Example:
        >>> import argparse
        >>> parser = argparse.ArgumentParser()
        >>> args = argparse.Namespace(quick=True, num_envs=8, seed=0)
        >>> config_from_args(parser, args, PPOConfig(), QUICK).num_envs, QUICK.num_envs
        (8, 32)
    """
    config = quick if args.quick else defaults
    overrides = {name: value for name, value in vars(args).items() if name in asdict(config) and value is not None}
    config = dataclasses.replace(config, **fixed, **overrides)
    problem = config_problem(config)
    if problem is not None:
        parser.error(problem)
    return config


def mlp(out_features: int, hidden: int) -> nn.Sequential:
    """Return ``PendulumFeatures`` followed by a two-hidden-layer tanh MLP."""
    return nn.Sequential(
        PendulumFeatures(),
        nn.Linear(3, hidden),
        nn.Tanh(),
        nn.Linear(hidden, hidden),
        nn.Tanh(),
        nn.Linear(hidden, out_features),
    )


def make_pendulum_env(task: Task, num_envs: int, seed: int) -> TransformedEnv:
    """Return ``num_envs`` pendulums with ``StepCounter(MAX_STEPS)``, ``TaskTransform(task)`` and ``RewardSum``."""
    return TransformedEnv(
        PendulumEnv(batch_size=[num_envs], seed=seed, max_torque=MAX_TORQUE, max_speed=MAX_SPEED),
        Compose(StepCounter(MAX_STEPS), TaskTransform(task), RewardSum()),
    )


def make_policy(env: TransformedEnv, hidden: int) -> tuple[ProbabilisticActor, ValueOperator]:
    """Return the actor (TanhNormal on ``[-MAX_TORQUE, MAX_TORQUE]``) and the critic."""
    actor_net = nn.Sequential(mlp(2, hidden), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -MAX_TORQUE, "high": MAX_TORQUE},
        return_log_prob=True,
        default_interaction_type=ExplorationType.RANDOM,
    )
    critic = ValueOperator(mlp(1, hidden), in_keys=["observation"])
    return actor, critic


@torch.no_grad()
def evaluate(
    policy: Callable[[TensorDictBase], TensorDictBase], make_env: EnvFactory, num_envs: int = EVAL_ENVS
) -> dict[str, float]:
    """Run one deterministic episode on each of ``num_envs`` pendulums of ``make_env`` from fixed initial states.

    The initial states are the same at every call: the evaluation env is seeded with ``EVAL_SEED``.
    Returns the success rate and the mean episode reward (task reward summed over the episode, the
    final reward included) of the first episode of every env, and the mean episode length. Every
    episode must end within ``MAX_STEPS`` (the env's ``StepCounter``).
    """
    env = make_env(num_envs, EVAL_SEED)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(MAX_STEPS, policy, break_when_any_done=False)
    nxt = rollout["next"]
    done = nxt["done"].squeeze(-1)  # [num_envs, MAX_STEPS]; every env is done by the last step
    first_end = done.int().argmax(dim=-1)
    rows = torch.arange(num_envs)
    success = nxt["success"].squeeze(-1)[rows, first_end]
    episode_reward = nxt["episode_reward"].squeeze(-1)[rows, first_end]
    return {
        "success_rate": success.float().mean().item(),
        "episode_reward": episode_reward.mean().item(),
        "episode_length": (first_end + 1).float().mean().item(),
    }


def machine_info() -> dict[str, Any]:
    """Return the CPU count, torch threads and the 1-minute load average (the machine is shared)."""
    return {"cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(), "load_1min": os.getloadavg()[0]}


def train(
    config: PPOConfig,
    seed: int,
    make_env: EnvFactory,
    make_eval_env: EnvFactory | None = None,
    max_iterations: int | None = None,
    stop_at_target: bool = True,
    description: str = "PPO swing-up",
    eval_envs: int = EVAL_ENVS,
) -> dict[str, Any]:
    """Train with PPO on the pendulums of ``make_env`` until the evaluation success rate reaches ``config.target``.

    After every batch the policy is evaluated (:func:`evaluate`) on ``eval_envs`` pendulums of
    ``make_eval_env`` (default: ``make_env``). The run stops at the first evaluation at
    ``config.target`` or above (unless ``stop_at_target`` is False: then it goes on), after
    ``max_iterations`` batches, or after ``config.max_minutes``. Returns the run record: config,
    seed, machine load, the learning curve (one point per evaluation) and the wall time and frames at
    which the target was first reached (None if not).
    """
    make_eval_env = make_env if make_eval_env is None else make_eval_env
    torch.manual_seed(seed)
    start = time.perf_counter()
    env = make_env(config.num_envs, seed)
    actor, critic = make_policy(env, config.hidden)
    advantage = GAE(gamma=config.gamma, lmbda=config.lmbda, value_network=critic, average_gae=False)
    loss_module = ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=config.clip_epsilon,
        entropy_coeff=config.entropy_coeff,
        critic_coeff=config.critic_coeff,
        loss_critic_type="l2",
        normalize_advantage=True,
    )
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=config.learning_rate)
    collector = Collector(
        env, actor, frames_per_batch=config.frames_per_batch, total_frames=-1, auto_register_policy_transforms=False
    )
    record: dict[str, Any] = {
        "method": "PPO",
        "config": asdict(config),
        "seed": seed,
        "machine_start": machine_info(),
        "target": config.target,
        "curve": [],
        "time_to_target_s": None,
        "frames_to_target": None,
    }
    deadline = start + 60.0 * config.max_minutes
    frames = 0
    bar = frame_bar(
        description,
        None if max_iterations is None else max_iterations * config.frames_per_batch,
        until=(f"{config.target:.0%} success or " if stop_at_target else "") + duration(60.0 * config.max_minutes),
    )
    for iteration, batch in enumerate(collector, start=1):
        frames += batch.numel()
        train_stats = episode_stats(batch)
        batch["next", "reward"] = batch["next", "reward"] * config.reward_scale
        with torch.no_grad():
            advantage(batch)
        ppo_update(
            loss_module,
            optimizer,
            batch.reshape(-1),
            epochs=config.epochs,
            minibatch_size=config.minibatch_size,
            max_grad_norm=config.max_grad_norm,
        )
        collector.update_policy_weights_()
        stats = evaluate(actor, make_eval_env, eval_envs)
        seconds = time.perf_counter() - start
        record["curve"].append(
            {
                "iteration": iteration,
                "frames": frames,
                "seconds": seconds,
                "eval_success_rate": stats["success_rate"],
                "eval_episode_reward": stats["episode_reward"],
                "eval_episode_length": stats["episode_length"],
                **train_stats,
            }
        )
        bar.set_postfix(success=f"{stats['success_rate']:.2f}", reward=f"{stats['episode_reward']:.0f}")
        bar.update(batch.numel())
        if stats["success_rate"] >= config.target:
            if record["frames_to_target"] is None:
                record["time_to_target_s"], record["frames_to_target"] = seconds, frames
            if stop_at_target:
                break
        if (max_iterations is not None and iteration >= max_iterations) or time.perf_counter() > deadline:
            break
    bar.close()
    collector.shutdown()
    last = record["curve"][-1]
    record.update(
        total_frames=frames,
        total_seconds=time.perf_counter() - start,
        final_success_rate=last["eval_success_rate"],
        final_episode_reward=last["eval_episode_reward"],
        machine_end=machine_info(),
    )
    return record


def ppo_update(
    loss_module: ClipPPOLoss,
    optimizer: torch.optim.Optimizer,
    data: TensorDictBase,
    *,
    epochs: int,
    minibatch_size: int,
    max_grad_norm: float,
) -> TensorDictBase:
    """Take the PPO gradient steps on one batch: ``epochs`` passes over ``data`` in shuffled minibatches.

    ``data`` is a flat batch of transitions with the advantages already computed (``GAE``). Every
    minibatch's loss (objective + critic + entropy, when the loss has an entropy term) is
    back-propagated, the gradient norm clipped at ``max_grad_norm`` and one optimizer step taken.
    Returns the losses of the last minibatch (detached), for logging.
    """
    losses = None
    for _ in range(epochs):
        for indices in torch.randperm(data.numel()).split(minibatch_size):
            losses = loss_module(data[indices])
            loss = losses["loss_objective"] + losses["loss_critic"]
            if "loss_entropy" in losses.keys():
                loss = loss + losses["loss_entropy"]
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(loss_module.parameters(), max_grad_norm)
            optimizer.step()
    if losses is None:
        raise ValueError(f"ppo_update: no gradient step (epochs={epochs}, {data.numel()} transitions)")
    return losses.detach()


def episode_stats(batch: TensorDictBase) -> dict[str, float | None]:
    """Success rate and mean episode reward of the episodes that ended in a training batch (None if none).

    The count and the success rate are :func:`~torchtasks.stats.episode_statistics` of the batch (the
    task's own flags). The reward is RewardSum's sum at each episode's last frame: a batch of 32 steps
    holds few whole episodes, and ``episode_statistics`` sums only those.
    """
    stats = episode_statistics(batch)
    count = int(stats["episodes"])
    if count == 0:
        return {"train_success_rate": None, "train_episode_reward": None, "train_episodes": 0}
    nxt = batch["next"]
    return {
        "train_success_rate": stats["success_rate"],
        "train_episode_reward": nxt["episode_reward"][nxt["done"]].mean().item(),
        "train_episodes": count,
    }


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the file-only ``Agg`` backend, or None after a message when matplotlib is not
    installed (the ``plot`` extra): a plot is skipped, the run's results are written all the same."""
    try:
        import matplotlib
    except ImportError:
        from torchtasks._optional import install_hint

        print(f"matplotlib is not installed ({install_hint('plot')}): the plot is skipped")
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: Path) -> Path:
    """Lay ``figure`` out, give its short series markers, write it to ``path`` (100 dpi; the folder is created) and
    close it; return ``path``."""
    import matplotlib.pyplot as plt

    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    mark_short_series(figure)  # a --quick run's few points stay visible
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def plot(runs: dict[str, dict[str, Any]], path: Path, title: str) -> Path:
    """Plot the evaluation success rate and mean episode reward of each run against env frames and wall time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter

    figure, axes = plt.subplots(2, 2, figsize=(10, 7), sharey="row")
    longest = max(point["seconds"] for record in runs.values() for point in record["curve"])
    scale, unit = time_unit(longest)
    for label, record in runs.items():
        curve = record["curve"]
        frames = [point["frames"] for point in curve]
        times = [point["seconds"] / scale for point in curve]
        for column, x in enumerate((frames, times)):
            axes[0, column].plot(x, [point["eval_success_rate"] for point in curve], marker=".", label=label)
            axes[1, column].plot(x, [point["eval_episode_reward"] for point in curve], marker=".", label=label)
    target = next(iter(runs.values()))["target"]
    for column in range(2):
        axes[0, column].axhline(target, color="grey", linestyle="--", linewidth=1, label=f"target {target:.0%}")
        axes[1, column].set_xlabel(("env frames", f"wall time [{unit}]")[column])
        axes[0, column].legend(loc="upper left")
    for axis in axes.flat:
        axis.grid(alpha=0.3)
    for axis in axes[:, 0]:
        axis.xaxis.set_major_formatter(EngFormatter())
    axes[0, 0].set_ylim(-0.02, 1.02)
    axes[0, 0].set_ylabel(f"success rate ({EVAL_ENVS} evaluation episodes)")
    axes[1, 0].set_ylabel("mean evaluation episode reward")
    figure.suptitle(title)
    return save_figure(figure, path)


def save(
    record: dict[str, Any], output: Path, name: str, title: str, others: dict[str, dict[str, Any]] | None = None
) -> tuple[Path, Path]:
    """Write the run record to ``name.json`` and its curve (with the curves of ``others``) to ``name.png``."""
    output.mkdir(parents=True, exist_ok=True)
    json_path = output / f"{name}.json"
    json_path.write_text(json.dumps(record, indent=2))
    return json_path, plot({record["method"]: record, **(others or {})}, output / f"{name}.png", title)
