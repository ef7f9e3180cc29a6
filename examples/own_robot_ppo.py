"""PPO on the shipped quadruped in the batched MuJoCo env, rewarded by a task on named readings (height, speed).

What it shows: a robot that is not a Gymnasium preset, end to end. :class:`~torchtasks.envs.BatchedMujocoEnv` on
the MJCF file ``torchtasks.envs.models.model_path("quadruped")`` (12 position servos, a free-floating torso, 64 envs
stepped by ``mujoco.batch`` in one process), its observation and task state declared by name with
:mod:`torchtasks.envs.readings`, actions as joint targets around the keyframe ``"home"``, resets from that keyframe
with noise on the velocities, and a task built from torchtasks' reward terms: a
:class:`~torchtasks.tasks.GoallessTask` whose reward is the :class:`~torchtasks.rewards.ProductReward` of two
tolerance factors, ``upright`` (the torso's height) and ``move`` (its forward velocity in its own frame), and whose
failure is a fall (the torso below 0.18 m leaves the task's state box). The docs page "Your own robot" builds the
same env step by step.

Set-up (:class:`OwnRobotPPOConfig`):

- Env: ``BatchedMujocoEnv(model_path("quadruped"), num_envs, observation=[...], state={"height": ...,
  "forward_velocity": ...}, actions=Actions(scale=0.5, offset="home"), resets=Resets(keyframe="home",
  qvel_noise=Noise("normal", 0.1)), frame_skip=4)`` (a 20 ms control step), then ``StepCounter(500)`` (10 s
  episodes), ``TaskTransform(task, state_key=["height", "forward_velocity"])``, ``ZeroBrokenStepReward``,
  ``RewardSum``, and for the policy only ``VecNormV2`` on ``"observation"``, clipping to ±10 and float32.
- Reward per step: ``upright * move`` in [0, 1]: ``upright`` is 1 at a torso height of 0.25 m and above, falling
  linearly to 0 at 0.18 m; ``move`` is ``(5 * speed + 1) / 6`` with ``speed`` 1 at 0.5 m/s forward and above,
  linearly 0 at standstill (dm_control's quadruped walk, in torchtasks' terms). An episode's return is at most 500.
- PPO as ``train_locomotion_ppo.py`` (its policy, critic, observation normalisation and ``PPOLearner`` with its
  return scaling, imported from there): batches of 64 envs x 32 steps, GAE (γ = 0.99, λ = 0.95), ``ClipPPOLoss``
  (clip 0.2, normalised advantages), 5 epochs of minibatches of 512, Adam 3e-4 annealed to 0, gradient norm clipped
  at 0.5; one torch thread, MuJoCo on 2 threads.
- Evaluation every ``eval_every`` frames and at the end: the deterministic policy (the mean action, observations
  normalised with the statistics of that moment) for 500 steps in ``eval_envs`` envs from fixed initial states;
  ``episode_statistics`` of it, and the mean forward velocity over all its frames.

Why the quadruped and not the shipped arm: at 64 envs the quadruped runs at about 7,000 frames/s with random
actions in the collector on 2 cores, and a random policy falls within about a second; within a few minutes of PPO
it learns to stay up and move forward, which the returns and the episode lengths show plainly.

Outputs in ``--output`` (default ``runs/own_robot_ppo``): ``own_robot_ppo_seed<N>.json`` (config, machine load at
start and end, a ``curve`` with one point per batch: frames, seconds, the mean return and length of the training
episodes that ended and their factors; an ``eval_curve``; totals) and ``own_robot_ppo_curve.png``: the returns of
every seed's JSON in that folder against frames and wall-clock time (needs matplotlib, the ``plot`` extra; without
it the plot is skipped with a message).

Run: ``python examples/own_robot_ppo.py [--seed 0] [--output DIR] [--quick]`` (``--quick``: a tiny run of a few
seconds that runs every code path, for the tests; ``--help`` lists the flags). Measured results: the docs page
"Your own robot".
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the other examples' modules

import torch
from _cli import duration, frame_bar
from _ppo_common import PPO_CONFIG_HELP, config_from_args, machine_info
from tensordict.nn import AddStateIndependentNormalScale
from torchrl.envs import (
    Compose,
    ExplorationType,
    RewardSum,
    StepCounter,
    TransformedEnv,
    VecNormV2,
    set_exploration_type,
)
from train_locomotion_ppo import PPOLearner, RunClock, make_policy, normalised, plot, training_returns

from torchtasks.envs import BatchedMujocoEnv, ZeroBrokenStepReward, readings
from torchtasks.envs.models import model_path
from torchtasks.envs.mujoco_declaration import Actions, FreeJointRanges, Noise, Resets
from torchtasks.rewards import AffineReward, ProductReward, ToleranceReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import GoallessTask
from torchtasks.transforms import TaskTransform

MODEL = "quadruped"
#: the twelve leg joints, in the order of the actuators
LEG_JOINTS = tuple(f"{leg}_{part}_joint" for leg in ("FL", "FR", "RL", "RR") for part in ("hip", "thigh", "calf"))
STATE_KEYS = ("height", "forward_velocity")
TERMS = ("upright", "move")  # the reward's named factors (TaskTransform writes them under "task_reward")
FALL_HEIGHT = 0.18  # m: the torso below this is a fall (a failure); it stands at 0.30 m
STAND_HEIGHT = 0.25  # m: upright is 1 from here up
TARGET_SPEED = 0.5  # m/s forward: move is 1 from here up
MAX_STEPS = 500  # 10 s at 50 Hz
EVAL_SEED = 12345  # the deterministic evaluations always start from the same initial states
DEFAULT_OUTPUT = Path("runs/own_robot_ppo")
PLOT_NAME = "own_robot_ppo_curve.png"


@dataclass(frozen=True)
class OwnRobotPPOConfig:
    """Hyper-parameters of a run (``frames_per_batch = num_envs * rollout_steps``)."""

    num_envs: int = 64
    rollout_steps: int = 32
    total_frames: int = 500_000
    epochs: int = 5
    minibatch_size: int = 512
    learning_rate: float = 3e-4
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    critic_coeff: float = 0.5
    max_grad_norm: float = 0.5
    hidden: int = 64
    mujoco_threads: int = 2
    eval_every: int = 100_000
    eval_envs: int = 16
    max_minutes: float = 10.0

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
    "learning_rate",
    "eval_every",
    "eval_envs",
    "max_minutes",
)

#: --quick: two batches of 4 envs x 50 steps, one evaluation of 2 envs at the end
QUICK = OwnRobotPPOConfig(
    num_envs=4, rollout_steps=50, total_frames=400, epochs=1, minibatch_size=200, eval_every=400, eval_envs=2
)


def file_name(seed: int | str) -> str:
    return f"own_robot_ppo_seed{seed}.json"


def make_task(action_space: Box) -> GoallessTask:
    """The task on the state ``[height, forward_velocity]``: reward ``upright * move``, failure below FALL_HEIGHT."""
    inf = float("inf")
    state_space = Box([FALL_HEIGHT, -inf], [inf, inf], labels=list(STATE_KEYS))  # leaving it is a failure: a fall
    upright = ToleranceReward(
        bounds=(STAND_HEIGHT, inf),
        margin=STAND_HEIGHT - FALL_HEIGHT,
        sigmoid="linear",
        value_at_margin=0.0,
        indices=["height"],
        space=state_space,
    )
    speed = ToleranceReward(
        bounds=(TARGET_SPEED, inf),
        margin=TARGET_SPEED,
        sigmoid="linear",
        value_at_margin=0.0,
        indices=["forward_velocity"],
        space=state_space,
    )
    reward = ProductReward({"upright": upright, "move": AffineReward(speed, scale=5 / 6, offset=1 / 6)})
    return GoallessTask(EnvSpec(state_space, action_space), reward)


def make_env(num_envs: int, seed: int, threads: int) -> TransformedEnv:
    """``num_envs`` quadrupeds with the task, ``StepCounter(MAX_STEPS)`` and ``RewardSum`` (no normalisation)."""
    base = BatchedMujocoEnv(
        model_path(MODEL),
        num_envs,
        observation=[  # one "observation" vector: what the policy sees
            readings.joint_pos(*LEG_JOINTS, relative_to="home"),
            readings.joint_vel(*LEG_JOINTS, clip=(-10.0, 10.0)),
            readings.sensor("imu_gyro"),
            readings.sensor("imu_vel"),
            readings.projected_gravity("torso"),
            readings.body_pos("torso", index=(2,)),
            readings.last_action(),
        ],
        state={  # the task's state, by name
            "height": readings.body_pos("torso", index=(2,)),
            "forward_velocity": readings.body_lin_vel("torso", frame="local", index=(0,)),
        },
        actions=Actions(scale=0.5, offset="home"),  # joint targets: home + 0.5 * action
        resets=Resets(  # the keyframe, each leg joint +-0.1 rad, velocities ~ N(0, 0.1), dropped from up to 2 cm
            keyframe="home",
            joint_noise={joint: Noise("uniform", 0.1) for joint in LEG_JOINTS},
            qvel_noise=Noise("normal", 0.1),
            free_joint=FreeJointRanges(position=((0.0, 0.0), (0.0, 0.0), (0.0, 0.02)), yaw=(-math.pi, math.pi)),
        ),
        frame_skip=4,
        seed=seed,
        num_threads=threads,
    )
    bounds = base.action_spec.space
    task = make_task(Box(bounds.low[0], bounds.high[0]))
    transforms = Compose(
        StepCounter(MAX_STEPS),
        TaskTransform(task, state_key=list(STATE_KEYS)),
        ZeroBrokenStepReward(),
        RewardSum(),
    )
    return TransformedEnv(base, transforms)


@torch.no_grad()
def evaluate(actor: torch.nn.Module, config: OwnRobotPPOConfig, vecnorm: VecNormV2) -> dict[str, float]:
    """The deterministic policy for MAX_STEPS steps in ``eval_envs`` envs: ``episode_statistics`` and the mean speed."""
    env = normalised(make_env(config.eval_envs, EVAL_SEED, config.mujoco_threads), vecnorm.to_observation_norm())
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(MAX_STEPS, actor, break_when_any_done=False)
    env.close()
    stats = episode_statistics(rollout)
    if not stats["complete_episodes"]:  # no env ended an episode: the running sums of the one episode each
        stats["return_mean"] = rollout["next", "episode_reward"][:, -1].mean().item()
        stats["episode_length_mean"] = float(MAX_STEPS)
    stats["forward_velocity_mean"] = rollout["next", "forward_velocity"].mean().item()
    return {key: value for key, value in stats.items() if not key.endswith(("/step", "/final"))}


def train(config: OwnRobotPPOConfig, seed: int) -> dict[str, Any]:
    """Train one seed for ``config.total_frames`` frames (or ``config.max_minutes``); return the run record."""
    torch.manual_seed(seed)
    clock = RunClock(config)
    env = make_env(config.num_envs, seed, config.mujoco_threads)
    vecnorm = VecNormV2(in_keys=["observation"], decay=1.0, eps=1e-2, reduce_batch_dims=True)
    env = normalised(env, vecnorm)
    actor, critic = make_policy(env, config.hidden)
    log_std = next(module for module in actor.modules() if isinstance(module, AddStateIndependentNormalScale))
    learner = PPOLearner(env, actor, critic, config)
    record: dict[str, Any] = {
        "model": MODEL,
        "env_id": f"the shipped {MODEL}",  # the plot's subject
        "max_steps": MAX_STEPS,
        "method": "PPO",
        "config": asdict(config),
        "seed": seed,
        "machine_start": machine_info(),
        "curve": [],
        "eval_curve": [],
    }
    frames = 0
    last_train, last_eval = None, None
    bar = frame_bar(f"PPO {MODEL} seed {seed}", clock.batches * config.frames_per_batch)
    for iteration, batch in enumerate(learner.collector, start=1):
        frames += batch.numel()
        batch_stats = episode_statistics(batch)
        returns = training_returns(batch, TERMS)
        losses = learner.update(batch, iteration)
        point = {
            "iteration": iteration,
            "frames": frames,
            "seconds": clock.seconds(),
            **returns,
            "episodes": batch_stats["episodes"],
            "episode_length_mean": batch_stats.get("episode_length_mean"),
            "failure_rate": batch_stats.get("failure_rate"),
            "loss_critic": losses["loss_critic"].item(),
            "action_scale": log_std.state_independent_scale.exp().mean().item(),
            "load_1min": machine_info()["load_1min"],
        }
        record["curve"].append(point)
        if returns["train_return"] is not None:
            last_train = point
        done = clock.is_last(iteration)
        stats = clock.evaluation(frames, done, lambda: evaluate(actor, config, vecnorm))
        if stats is not None:
            last_eval = {"iteration": iteration, "frames": frames, "seconds": clock.seconds(), **stats}
            record["eval_curve"].append(last_eval)
        postfix = {"ended": int(batch_stats["episodes"])}
        if last_train is not None:
            postfix["train_return"] = f"{last_train['train_return']:.0f}"
        if last_eval is not None:
            postfix["eval_return"] = f"{last_eval['return_mean']:.0f}"
        bar.set_postfix(postfix)
        bar.update(batch.numel())
        if done:
            break
    bar.close()
    learner.collector.shutdown()
    trained = [point for point in record["curve"] if point["train_return"] is not None]
    record.update(
        **clock.totals(frames),
        first_train_return=trained[0]["train_return"] if trained else None,
        final_train_return=trained[-1]["train_return"] if trained else None,
        first_eval_return=record["eval_curve"][0]["return_mean"],
        final_eval_return=last_eval["return_mean"],
        final_eval_forward_velocity=last_eval["forward_velocity_mean"],
        machine_end=machine_info(),
    )
    return record


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, DEFAULT_OUTPUT, "directory for the JSON and PNG")
    parser.add_argument("--seed", type=int, default=0, help="seed of the envs, the networks and the sampling")
    defaults = OwnRobotPPOConfig()
    config_arguments(parser, defaults, PPO_CONFIG_HELP, FLAGS)
    args = parser.parse_args()
    config = config_from_args(parser, args, defaults, QUICK)
    args.output = output_folder(parser, args, DEFAULT_OUTPUT)
    torch.set_num_threads(1)  # small networks: a second intra-op thread costs more than it gives on 2 cores
    record = train(config, args.seed)
    json_path = args.output / file_name(args.seed)
    json_path.write_text(json.dumps(record, indent=2))
    first, last = record["first_train_return"], record["final_train_return"]
    train_text = "no training episode ended" if last is None else f"training return {first:.1f} -> {last:.1f}"
    print(
        f"seed {args.seed}: {record['total_frames']} frames in {duration(record['total_seconds'])} "
        f"({record['frames_per_second']:.0f} frames/s; evaluation {record['eval_seconds']:.1f} s); {train_text}; "
        f"deterministic evaluation return {record['first_eval_return']:.1f} -> {record['final_eval_return']:.1f}, "
        f"forward velocity {record['final_eval_forward_velocity']:.2f} m/s; "
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
