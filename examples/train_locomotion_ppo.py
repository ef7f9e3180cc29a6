"""Train MuJoCo HalfCheetah-v5 with TorchRL's PPO on the batched env, rewarded by a torchtasks task.

What it shows: :func:`~torchtasks.envs.locomotion.gymnasium_env` (``num_envs`` HalfCheetahs stepped
in one process by :class:`~torchtasks.envs.BatchedMujocoEnv`, with ``StepCounter(1000)``, the
locomotion task's ``TaskTransform`` paying Gymnasium v5's exact reward, ``forward`` and ``ctrl``
terms, and ``RewardSum``) trained with the standard TorchRL PPO components on CPU: ``Collector``,
``GAE``, ``ClipPPOLoss``, a ``ProbabilisticActor`` with a ``TanhNormal`` and a state-independent
scale, a ``ValueOperator``; TorchRL's ``VecNormV2`` normalises the observations. The episode
statistics come from :func:`torchtasks.stats.episode_statistics`.

Set-up (:class:`LocomotionPPOConfig`; CleanRL's ``ppo_continuous_action`` hyper-parameters, except
the batch layout and the minibatch size):

- Env: ``gymnasium_env("HalfCheetah-v5", num_envs=N, seed=seed, num_threads=2)``, then
  ``VecNormV2`` on ``"observation"`` (running mean and variance of every observation collected,
  ``decay=1``, ``reduce_batch_dims=True``), ``ClipTransform`` to ±10 and ``DoubleToFloat``. The task
  still reads its raw float64 state entries (``x_velocity``); only the policy's input is normalised.
- Rewards for learning are divided by the running standard deviation of the discounted return
  (:class:`ReturnScaler`, as Gymnasium's ``NormalizeReward``) and clipped to ±10. The returns that
  are logged are the task's rewards, unscaled: Gymnasium's episode return.
- Policy: two 64-unit tanh layers (orthogonal init) giving the mean, a state-independent log-std
  (initially 0), ``TanhNormal`` on the action bounds [-1, 1]. Critic: the same MLP with one output.
- PPO: batches of 64 envs × 32 steps (2048 frames, CleanRL's 2048 steps of one env), GAE (γ = 0.99,
  λ = 0.95; the truncation at 1000 steps is bootstrapped, not treated as an end), 10 epochs of
  shuffled minibatches of 128 (CleanRL: 64; half the gradient steps, for time), ``ClipPPOLoss``
  (clip 0.2, no entropy bonus, L2 critic loss with coefficient 0.5, normalised advantages), Adam
  3e-4 (eps 1e-5) annealed linearly to 0 over the run, gradient norm clipped at 0.5.
- One torch thread (the networks are small); MuJoCo steps the envs on 2 threads.

Another env, more transforms: ``LocomotionPPOConfig.env_id`` (any of ``SUPPORTED_ENV_IDS``) and
the ``extra_transforms`` hook of :func:`make_env` and :func:`train` (appended to the preset before the
normalisation); ``train_hopper_domain_randomization.py`` trains Hopper with domain randomization that way.
Another preset: the ``preset`` argument of :func:`train` (``control_suite_ppo.py`` trains the Control Suite's).

Returns: HalfCheetah never terminates, so every episode ends at the 1000-step limit. The learning
curve is the **mean return of the training episodes that ended** in each batch (the stochastic
policy; RewardSum's episode sums of the reward and of its ``forward``/``ctrl`` terms at the
episode's last frame). All envs start together, so episodes end every ``1000 × num_envs`` frames.
Every ``eval_every`` frames and at the end, a **deterministic evaluation** (the policy's mean
action, observations normalised with the statistics of that moment, frozen) runs one 1000-step
episode in each of ``eval_envs`` envs from fixed initial states; its return and per-term returns are
``episode_statistics`` of that rollout. ``episode_statistics`` of every training batch gives the
count of ended episodes, their length and how they ended (shown in the progress bar).

Outputs in ``--output`` (default ``runs/train_locomotion_ppo``): ``locomotion_ppo_seed<N>.json``
per seed (config, machine load at start and end, a ``curve`` with one point per batch: frames,
seconds, training returns per term when episodes ended, 1-minute load average; an ``eval_curve``;
totals, among them ``collect_seconds``: the time spent waiting for the collector's batches) and
``locomotion_ppo_curve.png``: the return of every seed's JSON in that directory against
frames and against wall-clock time (needs matplotlib, the ``plot`` extra; without it the plot is
skipped with a message).

Run: ``python examples/train_locomotion_ppo.py [--seeds 0 1 2] [--output DIR] [--quick]`` (seeds run
one after the other; ``--quick``: a tiny run of a few seconds that runs every code path, for the
tests; ``--help`` lists the flags). Measured results: ``docs/training.md``.
"""

from __future__ import annotations

import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # _ppo_common.py, also when imported from elsewhere

import torch
from _cli import duration, frame_bar, time_unit
from _ppo_common import PPO_CONFIG_HELP, machine_info, ppo_update, pyplot, save_figure
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import (
    ClipTransform,
    DoubleToFloat,
    ExplorationType,
    Transform,
    TransformedEnv,
    VecNormV2,
    set_exploration_type,
)
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from torchtasks.envs.gymnasium_v5 import locomotion_record
from torchtasks.envs.locomotion import MAX_EPISODE_STEPS, gymnasium_env
from torchtasks.stats import episode_statistics
from torchtasks.transforms import TaskTransform

ENV_ID = "HalfCheetah-v5"  # the default env (LocomotionPPOConfig.env_id)
EVAL_SEED = 12345  # the deterministic evaluation always starts from the same initial states
OBSERVATION_CLIP = 10.0
REWARD_CLIP = 10.0
TERMS = locomotion_record(ENV_ID).term_names  # its named reward terms (TaskTransform writes them under "task_reward")
DEFAULT_OUTPUT = Path("runs/train_locomotion_ppo")
PLOT_NAME = "locomotion_ppo_curve.png"
GAE_NEXT_KEYS = (("next", "observation"), ("next", "done"), ("next", "terminated"))

#: ``seed -> transforms`` appended to the preset before the observation normalisation (e.g. a DomainRandomization)
ExtraTransforms = Callable[[int], Sequence[Transform]]


@dataclass(frozen=True)
class LocomotionPPOConfig:
    """Hyper-parameters of a run (``frames_per_batch = num_envs * rollout_steps``)."""

    env_id: str = ENV_ID
    num_envs: int = 64
    rollout_steps: int = 32
    total_frames: int = 1_000_000
    epochs: int = 10
    minibatch_size: int = 128
    learning_rate: float = 3e-4
    anneal_lr: bool = True
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    critic_coeff: float = 0.5
    max_grad_norm: float = 0.5
    hidden: int = 64
    mujoco_threads: int = 2
    eval_every: int = 100_000
    eval_envs: int = 16
    eval_steps: int = MAX_EPISODE_STEPS
    max_minutes: float = 30.0

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.rollout_steps


#: the config fields that are command-line flags (``--num-envs`` for ``num_envs``), described by PPO_CONFIG_HELP
FLAGS = (
    "num_envs",
    "rollout_steps",
    "total_frames",
    "epochs",
    "minibatch_size",
    "eval_every",
    "eval_envs",
    "eval_steps",
    "learning_rate",
    "max_minutes",
)

#: --quick: two batches of 4 envs x 500 steps, so that the training episodes end (at step 1000) in the run
QUICK = LocomotionPPOConfig(
    num_envs=4, rollout_steps=500, total_frames=4000, epochs=1, minibatch_size=1000, eval_every=4000, eval_envs=2
)


def file_name(seed: int | str) -> str:
    return f"locomotion_ppo_seed{seed}.json"


#: ``(env_id, *, num_envs, seed, num_threads) -> env``: a preset the PPO examples train on (``gymnasium_env``'s stack)
Preset = Callable[..., TransformedEnv]


def normalised(env: TransformedEnv, observation_norm: Transform) -> TransformedEnv:
    """Append ``observation_norm`` (a VecNormV2 or its frozen copy), clipping to ±10 and float32 to ``env``."""
    with warnings.catch_warnings():  # "experimental" for batched envs; reduce_batch_dims is what a batch needs
        warnings.filterwarnings("ignore", message="Support of VecNormV2 for containers", category=UserWarning)
        env.append_transform(observation_norm)
    env.append_transform(ClipTransform(in_keys=["observation"], low=-OBSERVATION_CLIP, high=OBSERVATION_CLIP))
    env.append_transform(DoubleToFloat(in_keys=["observation"]))
    return env


def make_env(
    config: LocomotionPPOConfig,
    seed: int,
    extra_transforms: ExtraTransforms | None = None,
    preset: Preset = gymnasium_env,
) -> tuple[TransformedEnv, VecNormV2]:
    """Return the training env (the preset, then observation normalisation, clipping and float32) and its VecNormV2.

    ``extra_transforms(seed)``, if given, are appended to the preset before the normalisation. ``preset``: the
    env factory called with ``config.env_id`` (default :func:`~torchtasks.envs.locomotion.gymnasium_env`).
    """
    env = preset(config.env_id, num_envs=config.num_envs, seed=seed, num_threads=config.mujoco_threads)
    for transform in extra_transforms(seed) if extra_transforms is not None else ():
        env.append_transform(transform)
    vecnorm = VecNormV2(in_keys=["observation"], decay=1.0, eps=1e-2, reduce_batch_dims=True)
    return normalised(env, vecnorm), vecnorm


def make_eval_env(
    config: LocomotionPPOConfig,
    vecnorm: VecNormV2,
    extra_transforms: ExtraTransforms | None = None,
    preset: Preset = gymnasium_env,
) -> TransformedEnv:
    """Return ``eval_envs`` envs from fixed initial states, normalised with ``vecnorm``'s current statistics, frozen.

    ``extra_transforms(EVAL_SEED)``, if given, are appended to the preset before the normalisation; ``preset``: as
    for :func:`make_env`.
    """
    env = preset(config.env_id, num_envs=config.eval_envs, seed=EVAL_SEED, num_threads=config.mujoco_threads)
    for transform in extra_transforms(EVAL_SEED) if extra_transforms is not None else ():
        env.append_transform(transform)
    return normalised(env, vecnorm.to_observation_norm())


def mlp(in_features: int, out_features: int, hidden: int, output_gain: float) -> nn.Sequential:
    """Two tanh layers, orthogonal init (gain √2, output layer ``output_gain``), zero biases (as CleanRL)."""
    layers = [nn.Linear(in_features, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh()]
    layers.append(nn.Linear(hidden, out_features))
    for layer in layers:
        if isinstance(layer, nn.Linear):
            gain = output_gain if layer is layers[-1] else math.sqrt(2.0)
            nn.init.orthogonal_(layer.weight, gain)
            nn.init.zeros_(layer.bias)
    return nn.Sequential(*layers)


def make_policy(env: TransformedEnv, hidden: int, values: int = 1) -> tuple[ProbabilisticActor, ValueOperator]:
    """Return the actor (``TanhNormal`` on the action bounds, state-independent scale) and the critic.

    The critic writes ``values`` values per observation to ``"state_value"`` (one critic per reward group: ``k``).
    """
    n_obs = env.observation_spec["observation"].shape[-1]
    action_spec = env.action_spec
    n_act = action_spec.shape[-1]
    actor_net = nn.Sequential(mlp(n_obs, n_act, hidden, 0.01), AddStateIndependentNormalScale(n_act, scale_lb=1e-8))
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={
            "low": action_spec.space.low[0].clone(),
            "high": action_spec.space.high[0].clone(),
            "tanh_loc": False,
        },
        return_log_prob=True,
        default_interaction_type=ExplorationType.RANDOM,
    )
    critic = ValueOperator(mlp(n_obs, values, hidden, 1.0), in_keys=["observation"])
    return actor, critic


class ReturnScaler:
    """Divide rewards by the running standard deviation of the discounted return, then clip them.

    Gymnasium's ``NormalizeReward`` (used by CleanRL's PPO), on collected ``[envs, time]`` batches:
    every env keeps its discounted return ``G = γ G + r`` (reset to 0 after a ``done`` frame), the
    variance of all ``G`` seen so far is tracked with a parallel running-moments update, and the
    rewards are divided by ``sqrt(var + 1e-8)`` and clipped to ``±clip``.

    Example:
        >>> scaler = ReturnScaler(num_envs=1, gamma=0.0)
        >>> reward = torch.tensor([[1.0, 3.0]], dtype=torch.float64)
        >>> scaler(reward, torch.zeros(1, 2, dtype=torch.bool))  # γ = 0: G = r, and the std of {1, 3} is 1
        tensor([[0.9999, 2.9997]])
    """

    def __init__(self, num_envs: int, gamma: float, clip: float = REWARD_CLIP, epsilon: float = 1e-8) -> None:
        self.gamma, self.clip, self.epsilon = gamma, clip, epsilon
        self.returns = torch.zeros(num_envs, dtype=torch.float64)
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4  # Gymnasium's RunningMeanStd prior

    def __call__(self, reward: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Scale ``reward`` ``[envs, time]`` (float64) given the ``done`` flags ``[envs, time]``; return float32.

        :meth:`update` with ``reward``, then :meth:`scale` of it.
        """
        self.update(reward, done)
        return self.scale(reward)

    def scale(self, reward: torch.Tensor) -> torch.Tensor:
        """``reward`` (any shape) divided by the running standard deviation of the return, clipped, as float32."""
        return (reward / math.sqrt(self.var + self.epsilon)).clamp(-self.clip, self.clip).float()

    def update(self, reward: torch.Tensor, done: torch.Tensor) -> None:
        """Add the discounted returns of ``reward`` ``[envs, time]`` (float64, cut where ``done``) to the moments."""
        discounted = torch.empty_like(reward, dtype=torch.float64)
        for t in range(reward.shape[1]):
            self.returns = self.returns * self.gamma + reward[:, t]
            discounted[:, t] = self.returns
            self.returns = torch.where(done[:, t], 0.0, self.returns)
        batch_mean = discounted.mean().item()
        batch_var = discounted.var(unbiased=False).item()
        batch_count = discounted.numel()
        delta = batch_mean - self.mean
        total = self.count + batch_count
        self.mean += delta * batch_count / total
        self.var = (
            self.var * self.count + batch_var * batch_count + delta**2 * self.count * batch_count / total
        ) / total
        self.count = total


def clip_ppo_loss(
    actor: ProbabilisticActor, critic: ValueOperator, config: Any, normalize_advantage: bool = True
) -> ClipPPOLoss:
    """``ClipPPOLoss`` as the MuJoCo PPO examples use it: clipping at ``config.clip_epsilon``, no entropy bonus, an L2
    critic loss weighted ``config.critic_coeff``, the advantages normalised per minibatch (``normalize_advantage``)."""
    return ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=config.clip_epsilon,
        entropy_bonus=False,
        critic_coeff=config.critic_coeff,
        loss_critic_type="l2",
        normalize_advantage=normalize_advantage,
    )


class PPOLearner:
    """The PPO of the MuJoCo examples on one env: a Collector of ``actor``, GAE on rewards scaled by a
    :class:`ReturnScaler`, :func:`clip_ppo_loss` (no entropy bonus, normalised advantages, L2 critic loss) and Adam (eps
    1e-5) whose learning rate is annealed linearly to 0 over the run's ``iterations`` batches (``anneal_lr``).

    ``config`` gives ``num_envs``, ``rollout_steps`` (``frames_per_batch``), ``total_frames``, ``gamma``, ``lmbda``,
    ``clip_epsilon``, ``critic_coeff``, ``learning_rate``, ``epochs``, ``minibatch_size`` and ``max_grad_norm``. The
    parts are built in the order of a run's random draws: GAE, the loss, Adam, the Collector (which resets the env).
    """

    def __init__(
        self, env: TransformedEnv, actor: ProbabilisticActor, critic: ValueOperator, config: Any, anneal_lr: bool = True
    ) -> None:
        self.config, self.anneal_lr = config, anneal_lr
        self.advantage = GAE(gamma=config.gamma, lmbda=config.lmbda, value_network=critic, average_gae=False)
        self.loss_module = clip_ppo_loss(actor, critic, config)
        self.optimizer = torch.optim.Adam(self.loss_module.parameters(), lr=config.learning_rate, eps=1e-5)
        self.collector = Collector(
            env, actor, frames_per_batch=config.frames_per_batch, total_frames=-1, auto_register_policy_transforms=False
        )
        self.scaler = ReturnScaler(config.num_envs, config.gamma)
        self.iterations = math.ceil(config.total_frames / config.frames_per_batch)

    def update(self, batch: TensorDictBase, iteration: int) -> TensorDictBase:
        """The PPO update on the ``iteration``-th collected ``batch`` (``[envs, time]``), then the collector's policy
        weights; returns the last minibatch's losses (:func:`~_ppo_common.ppo_update`)."""
        config = self.config
        if self.anneal_lr:
            for group in self.optimizer.param_groups:
                group["lr"] = config.learning_rate * (1.0 - (iteration - 1) / self.iterations)
        # only what GAE and the loss read: indexing minibatches out of the full batch costs more
        data = batch.select("observation", "action", "action_log_prob", *GAE_NEXT_KEYS)
        reward = self.scaler(batch["next", "reward"].squeeze(-1), batch["next", "done"].squeeze(-1))
        data["next", "reward"] = reward.unsqueeze(-1)
        with torch.no_grad():
            self.advantage(data)
        losses = ppo_update(
            self.loss_module,
            self.optimizer,
            data.exclude("next").reshape(-1),
            epochs=config.epochs,
            minibatch_size=config.minibatch_size,
            max_grad_norm=config.max_grad_norm,
        )
        self.collector.update_policy_weights_()
        return losses


class RunClock:
    """The wall clock of a training run of ``config``, started when built: its last batch (all
    ``ceil(total_frames / frames_per_batch)`` batches, or the first past ``max_minutes``), its evaluations (every
    ``eval_every`` frames and after the last batch), the time they took, and the run's totals."""

    def __init__(self, config: Any) -> None:
        self.start = time.perf_counter()
        self.deadline = self.start + 60.0 * config.max_minutes
        self.batches = math.ceil(config.total_frames / config.frames_per_batch)
        self.frames_per_batch, self.eval_every = config.frames_per_batch, config.eval_every
        self.next_eval, self.eval_seconds = config.eval_every, 0.0

    def seconds(self) -> float:
        """The seconds since the run started."""
        return time.perf_counter() - self.start

    def is_last(self, iteration: int) -> bool:
        """Whether the ``iteration``-th batch ends the run."""
        return iteration >= self.batches or time.perf_counter() > self.deadline

    def evaluation(self, frames: int, last: bool, evaluate: Callable[[], dict[str, Any]]) -> dict[str, Any] | None:
        """``evaluate()`` if one is due after ``frames`` frames (or after the ``last`` batch), timed; else None."""
        if frames < self.next_eval and not last:
            return None
        eval_start = time.perf_counter()
        stats = evaluate()
        self.eval_seconds += time.perf_counter() - eval_start
        self.next_eval += self.eval_every
        return stats

    def totals(self, frames: int) -> dict[str, Any]:
        """The run's frames, seconds (in all and evaluating), frames per second and whether the deadline stopped it."""
        total_seconds = self.seconds()
        return {
            "total_frames": frames,
            "total_seconds": total_seconds,
            "eval_seconds": self.eval_seconds,
            "frames_per_second": frames / total_seconds,
            "stopped_by_time_limit": frames < self.batches * self.frames_per_batch,
        }


def training_returns(batch: TensorDictBase, terms: Sequence[str] = TERMS) -> dict[str, float | None]:
    """Mean return (and per-term returns) of the training episodes that ended in ``batch``, from RewardSum's sums.

    The episodes are 1000 steps long and a batch holds ``rollout_steps`` of them, so the returns come
    from RewardSum's running sums at the last frame of every ended episode, not from
    ``episode_statistics`` (which sums only episodes whose frames are all in the batch). ``terms``: the
    env's named reward terms.
    """
    nxt = batch["next"]
    done = nxt["done"]
    if not bool(done.any()):
        return {"train_return": None, **{f"train_return/{term}": None for term in terms}}
    stats = {"train_return": nxt["episode_reward"][done].mean().item()}
    for term in terms:
        stats[f"train_return/{term}"] = nxt["task_reward", f"episode_{term}"][done].mean().item()
    return stats


def reward_terms(env: TransformedEnv) -> tuple[str, ...]:
    """The named terms of the reward of ``env``'s task (its one TaskTransform), which RewardSum sums per episode."""
    tasks = [transform.task for transform in env.transform if isinstance(transform, TaskTransform)]
    if len(tasks) != 1:
        raise ValueError(f"the env needs one TaskTransform, got {len(tasks)}")
    return tasks[0].term_names


@torch.no_grad()
def evaluate(
    actor: ProbabilisticActor, config: LocomotionPPOConfig, vecnorm: VecNormV2, preset: Preset = gymnasium_env
) -> dict[str, float]:
    """One deterministic episode (``eval_steps`` steps) in each of ``eval_envs`` envs; ``episode_statistics`` of it.

    ``preset``: as for :func:`make_env`.
    """
    env = make_eval_env(config, vecnorm, preset=preset)
    terms = reward_terms(env)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(config.eval_steps, actor, break_when_any_done=False)
    env.close()
    stats = episode_statistics(rollout)
    if not stats["complete_episodes"]:  # --eval-steps below the episode length: the returns of the partial episodes
        stats["return_mean"] = rollout["next", "episode_reward"][:, -1].mean().item()
        for term in terms:
            stats[f"return_mean/{term}"] = rollout["next", "task_reward", f"episode_{term}"][:, -1].mean().item()
    return {key: value for key, value in stats.items() if not key.endswith(("/step", "/final"))}


def train(
    config: LocomotionPPOConfig,
    seed: int,
    extra_transforms: ExtraTransforms | None = None,
    preset: Preset = gymnasium_env,
) -> dict[str, Any]:
    """Train one seed for ``config.total_frames`` frames (or ``config.max_minutes``); return the run record.

    ``extra_transforms``: see :func:`make_env` (the training env only; the evaluations run the preset). ``preset``:
    the env factory called with ``config.env_id`` (default :func:`~torchtasks.envs.locomotion.gymnasium_env`; any
    factory of a ``TransformedEnv`` with one ``TaskTransform``, ``StepCounter`` and ``RewardSum``, whose
    ``"observation"`` is one vector: ``control_suite_ppo.py`` passes the Control Suite's).
    """
    return train_policy(config, seed, extra_transforms, preset)[0]


def train_policy(
    config: LocomotionPPOConfig,
    seed: int,
    extra_transforms: ExtraTransforms | None = None,
    preset: Preset = gymnasium_env,
) -> tuple[dict[str, Any], ProbabilisticActor, VecNormV2]:
    """:func:`train`, also returning the trained actor and the training env's VecNormV2 (for further evaluations)."""
    torch.manual_seed(seed)
    clock = RunClock(config)
    env, vecnorm = make_env(config, seed, extra_transforms, preset)
    terms = reward_terms(env)
    actor, critic = make_policy(env, config.hidden)
    log_std = next(module for module in actor.modules() if isinstance(module, AddStateIndependentNormalScale))
    learner = PPOLearner(env, actor, critic, config, anneal_lr=config.anneal_lr)
    record: dict[str, Any] = {
        "env_id": config.env_id,
        "method": "PPO",
        "config": asdict(config),
        "seed": seed,
        "machine_start": machine_info(),
        "curve": [],
        "eval_curve": [],
    }
    frames = 0
    # collection: from the end of one batch's update (or the start) until the collector hands over the next batch
    collect_seconds, collect_start = 0.0, time.perf_counter()
    last_train, last_eval = None, None
    bar = frame_bar(f"PPO {config.env_id} seed {seed}", clock.batches * config.frames_per_batch)  # whole batches
    for iteration, batch in enumerate(learner.collector, start=1):
        collect_seconds += time.perf_counter() - collect_start
        frames += batch.numel()
        batch_stats = episode_statistics(batch)
        returns = training_returns(batch, terms)
        losses = learner.update(batch, iteration)
        point = {
            "iteration": iteration,
            "frames": frames,
            "seconds": clock.seconds(),
            **returns,
            "episodes": batch_stats["episodes"],
            "episode_length_mean": batch_stats.get("episode_length_mean"),
            "timeout_rate": batch_stats.get("timeout_rate"),
            # with a DomainRandomization: the mean physics of the episodes that ended ("domain/<field>")
            **{key: value for key, value in batch_stats.items() if key.startswith("domain/")},
            "loss_critic": losses["loss_critic"].item(),
            "clip_fraction": losses["clip_fraction"].item(),
            "action_scale": log_std.state_independent_scale.exp().mean().item(),  # of the Normal before tanh
            "load_1min": machine_info()["load_1min"],
        }
        record["curve"].append(point)
        if returns["train_return"] is not None:
            last_train = returns
        done = clock.is_last(iteration)
        stats = clock.evaluation(frames, done, lambda: evaluate(actor, config, vecnorm, preset))
        if stats is not None:
            last_eval = {"iteration": iteration, "frames": frames, "seconds": clock.seconds(), **stats}
            record["eval_curve"].append(last_eval)
        postfix = {"ended": int(batch_stats["episodes"])}
        if last_train is not None:
            postfix["train_return"] = f"{last_train['train_return']:.0f}"
            postfix.update({term: f"{last_train[f'train_return/{term}']:.0f}" for term in terms})
        if last_eval is not None:
            postfix["eval_return"] = f"{last_eval['return_mean']:.0f}"
        bar.set_postfix(postfix)
        bar.update(batch.numel())
        if done:
            break
        collect_start = time.perf_counter()
    bar.close()
    learner.collector.shutdown()
    record.update(
        **clock.totals(frames),
        collect_seconds=collect_seconds,
        collect_frames_per_second=frames / collect_seconds,
        final_train_return=None if last_train is None else last_train["train_return"],
        final_train_frames=None if last_train is None else _frames_of_last_train_return(record["curve"]),
        final_eval_return=last_eval["return_mean"],
        machine_end=machine_info(),
    )
    return record, actor, vecnorm


def _frames_of_last_train_return(curve: list[dict[str, Any]]) -> int:
    return next(point["frames"] for point in reversed(curve) if point["train_return"] is not None)


def plot(records: list[dict[str, Any]], path: Path) -> Path | None:
    """Plot every run's training and evaluation returns against frames and wall time; None without matplotlib."""
    plt = pyplot()
    if plt is None:
        return None
    from matplotlib.ticker import EngFormatter

    figure, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
    seconds_per_unit, unit = time_unit(max(record["total_seconds"] for record in records))
    for index, record in enumerate(sorted(records, key=lambda record: record["seed"])):
        color = f"C{index}"
        train = [point for point in record["curve"] if point["train_return"] is not None]
        evals = record["eval_curve"]
        for axis, key, scale in ((axes[0], "frames", 1.0), (axes[1], "seconds", 1 / seconds_per_unit)):
            axis.plot(
                [point[key] * scale for point in train],
                [point["train_return"] for point in train],
                color=color,
                marker=".",
                label=f"seed {record['seed']}, training episodes",
            )
            axis.plot(
                [point[key] * scale for point in evals],
                [point["return_mean"] for point in evals],
                color=color,
                linestyle="--",
                marker="x",
                label=f"seed {record['seed']}, deterministic evaluation",
            )
    axes[0].xaxis.set_major_formatter(EngFormatter())
    axes[0].set_xlabel("env frames")
    axes[1].set_xlabel(f"wall-clock time [{unit}]")
    axes[0].set_ylabel(f"mean episode return ({records[0].get('max_steps', 1000)} steps)")
    axes[0].legend(fontsize="small")
    for axis in axes:
        axis.grid(alpha=0.3)
    config = records[0]["config"]
    layout = f"{config['num_envs']} envs x {config['rollout_steps']} steps per batch"
    figure.suptitle(f"PPO on {records[0]['env_id']} (BatchedMujocoEnv, {layout})")
    return save_figure(figure, path)


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSONs and PNG")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds, trained one after the other")
    defaults = LocomotionPPOConfig()
    config_arguments(parser, defaults, PPO_CONFIG_HELP, FLAGS)
    args = parser.parse_args()
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    config = QUICK if args.quick else defaults
    overrides = {name: value for name, value in vars(args).items() if name in asdict(config) and value is not None}
    config = replace(config, **overrides)
    for seed in args.seeds:
        record = train(config, seed)
        json_path = args.output / file_name(seed)
        json_path.write_text(json.dumps(record, indent=2))
        train_return = record["final_train_return"]
        train_text = (
            "no training episode ended"
            if train_return is None
            else (f"training return {train_return:.1f} (episodes ended at {record['final_train_frames']} frames)")
        )
        print(
            f"seed {seed}: {record['total_frames']} frames in {duration(record['total_seconds'])} "
            f"({record['frames_per_second']:.0f} frames/s; collection {duration(record['collect_seconds'])}, "
            f"{record['collect_frames_per_second']:.0f} frames/s; evaluation {record['eval_seconds']:.1f} s); "
            f"{train_text}; "
            f"deterministic evaluation return {record['final_eval_return']:.1f}; "
            f"1-min load average {record['machine_start']['load_1min']:.2f} at start, "
            f"{record['machine_end']['load_1min']:.2f} at end"
        )
        print(f"wrote {json_path}")
    records = [json.loads(path.read_text()) for path in sorted(args.output.glob(file_name("*")))]
    png = plot(records, args.output / PLOT_NAME)
    if png is not None:
        print(f"wrote {png} ({len(records)} seed{'' if len(records) == 1 else 's'})")


if __name__ == "__main__":
    from _cli import add_output_argument, config_arguments, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
