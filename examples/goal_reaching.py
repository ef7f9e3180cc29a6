"""Goal reaching on a 2-D point mass with TorchRL's TD3, with and without hindsight relabelling (HER).

What it shows: goals sampled per env by a :class:`~torchtasks.transforms.GoalCommand` and seen by the
policy, a sparse goal-reaching task applied by :class:`~torchtasks.transforms.TaskTransform` (reward,
success, episode end), and the same task relabelling stored transitions in TorchRL's
``HERReplayBuffer`` through ``TaskTransform.relabel``. The agent is TorchRL's TD3 (``TD3Loss``,
``SoftUpdate``) trained off-policy from a replay buffer: a ``HERReplayBuffer`` (``"future"``
strategy, ``her_ratio`` 0.8) or a plain ``TensorDictReplayBuffer``, the rest being identical.

Set-up:

- Env: :class:`~torchtasks.envs.PointMassEnv` (state ``[x, y, vx, vy]``, a 2-D force clipped to
  ``±MAX_FORCE`` = 2, dt 0.05 s, damping 0.5, walls at ±1), 16 masses stepped as one tensor;
  resets put the mass uniformly in the box at rest. ``StepCounter(MAX_STEPS)`` truncates episodes.
- Goals: ``GoalCommand(Box([-0.8, -0.8], [0.8, 0.8]))`` draws a goal position at every reset (for the
  envs being reset only) into ``"goal"``; the policy and the critics see ``[observation, goal]``.
- Task (Gymnasium-Robotics style sparse reward): ``FinalRewardTask(MaskedTask(spec,
  DesiredStateTask(position sub-spec, [0, 0], ConstantReward(-1), success=proximity_succeeded(0.1)),
  ["x", "y"]), always_positive, factor 1)``: -1 per step, 0 in the step that reaches the goal
  (``‖(x, y) − goal‖ < 0.1``; -1 + the final +1), and success ends the episode. The transform reads the goal
  the policy saw (``goal_key="goal"``) and writes the achieved goal ``(x, y)`` (``achieved_goal_key``).
- HER: ``HERReplayBuffer(reward_fn=transform.relabel, goal_key="goal",
  achieved_goal_key=("next", "achieved_goal"), end_key=("next", "segment_end"))``. The buffer holds
  each env's steps of one collection in order; ``segment_end`` marks episode ends and the end of each
  env's row (so no goal comes from another env). The buffer rewrites ``goal`` and ``("next", "goal")``;
  ``relabel`` re-judges each relabelled transition for its new goal and writes the reward and, in place,
  ``success``, ``terminated`` and ``done`` (with ``reward_fn`` alone a relabelled transition that reaches
  its new goal would keep ``terminated=False`` and its target would bootstrap past the success).
- Evaluation: every ``Config.eval_every`` (2,000) frames, the deterministic policy (no noise) runs one
  episode on each of ``EVAL_ENVS`` envs with fixed initial states and fixed goals (seed ``EVAL_SEED``);
  success rate = fraction of first episodes that reach their goal. A run stops at ``--target`` (0.9)
  or at the frame budget.
- TD3 (:class:`Config`): actor and twin critics with two 128-unit ReLU layers, Adam 1e-3, γ 0.95,
  τ 0.01, batches of 256, 200 gradient steps per collection of 16 envs × 25 steps, actor and targets
  updated every 2nd step, 2,000 uniform random warm-up frames, Gaussian action noise of std
  0.3·``MAX_FORCE``; a frame budget of 24,000 per run.
- One torch thread (small ops on a shared 2-core machine).

Outputs in ``--output`` (default ``runs/goal_reaching/``): ``goal_reaching.json`` (config, per run the
curve and the frames to the target, per variant the frames to target of every seed) and
``goal_reaching.png`` (evaluation success rate against frames, one line per run).

Run: ``python examples/goal_reaching.py [--quick] [--seeds 0 1 2] [--variants her plain] [--frames N]``
(``--quick``: a tiny run of a few seconds that runs every code path, for the tests).
"""

from __future__ import annotations

import functools
import json
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch
from _cli import duration, frame_bar
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded, HERReplayBuffer, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import Compose, StepCounter, TransformedEnv
from torchrl.objectives import SoftUpdate, TD3Loss

from torchtasks._plotting import mark_short_series
from torchtasks.envs import PointMassEnv
from torchtasks.rewards import ConstantReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.tasks.final_reward import FinalRewardMode
from torchtasks.transforms import GoalCommand, TaskTransform

MAX_FORCE = 2.0
MAX_STEPS = 50  # 2.5 s per episode
SUCCESS_RADIUS = 0.1
GOAL_SPACE = Box([-0.8, -0.8], [0.8, 0.8])
EVAL_ENVS = 200
EVAL_SEED = 12345
SEGMENT_END_KEY = ("next", "segment_end")


@dataclass(frozen=True)
class Config:
    """Sizes and hyper-parameters of one TD3 run."""

    num_envs: int = 16
    steps_per_collection: int = 25  # steps of every env between two training phases
    updates_per_collection: int = 200  # gradient steps after each collection (num_envs*steps/updates frames each)
    warmup_frames: int = 2_000  # uniform random actions before the first update
    total_frames: int = 24_000  # frame budget of one run
    eval_every: int = 2_000
    batch_size: int = 256
    buffer_size: int = 200_000
    her_ratio: float = 0.8
    gamma: float = 0.95
    tau: float = 0.01
    lr: float = 1e-3
    hidden: int = 128
    exploration_noise: float = 0.3  # std of the Gaussian action noise, in units of MAX_FORCE
    policy_delay: int = 2
    target: float = 0.9


QUICK = Config(
    num_envs=4, steps_per_collection=10, updates_per_collection=4, warmup_frames=40, total_frames=160,
    eval_every=80, batch_size=32, buffer_size=1_000, hidden=16,
)  # fmt: skip


def make_task() -> FinalRewardTask:
    """-1 per step until ``‖(x, y) − goal‖ < SUCCESS_RADIUS``; +1 once in the step that reaches it; success ends."""
    inf = float("inf")
    states = Box([-1.0, -1.0, -inf, -inf], [1.0, 1.0, inf, inf], labels=PointMassEnv.labels)
    spec = EnvSpec(states, Box([-MAX_FORCE] * 2, [MAX_FORCE] * 2))
    near = functools.partial(proximity_succeeded, threshold=SUCCESS_RADIUS)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], ConstantReward(-1.0), success=near)
    return FinalRewardTask(MaskedTask(spec, reach, ["x", "y"]), FinalRewardMode(always_positive=True), factor=1.0)


def make_env(num_envs: int, seed: int) -> TransformedEnv:
    """Point masses + ``StepCounter`` + the task (goal read from ``"goal"``) + ``GoalCommand`` (goals at reset)."""
    transforms = Compose(
        StepCounter(MAX_STEPS),
        TaskTransform(make_task(), goal_key="goal", achieved_goal_key="achieved_goal", log_terms=False),
        GoalCommand(GOAL_SPACE, goal_key="goal", seed=seed),
    )
    return TransformedEnv(PointMassEnv(batch_size=[num_envs], max_force=MAX_FORCE, seed=seed), transforms)


class Actor(nn.Module):
    """``[observation, goal] -> force`` in ``[-MAX_FORCE, MAX_FORCE]²``."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(6, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 2)
        )

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return MAX_FORCE * torch.tanh(self.net(torch.cat((observation, goal), -1)))


class Critic(nn.Module):
    """``[observation, goal, action] -> Q``."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(8, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1)
        )

    def forward(self, observation: torch.Tensor, goal: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat((observation, goal, action / MAX_FORCE), -1))


def evaluate(actor: TensorDictModule, num_envs: int = EVAL_ENVS) -> float:
    """Success rate of the deterministic policy over one episode on each of ``num_envs`` fixed (start, goal) pairs."""
    env = make_env(num_envs, EVAL_SEED)
    with torch.no_grad():
        data = env.rollout(MAX_STEPS, actor, break_when_any_done=False)
    done = data["next", "done"][..., 0].long()
    first_episode = (done.cumsum(-1) - done) == 0  # steps up to and including the end of the first episode
    return (data["next", "success"][..., 0] & first_episode).any(-1).float().mean().item()


def mark_rows(batch: TensorDictBase) -> TensorDictBase:
    """``[envs, steps]`` -> ``[envs * steps]`` (each env's steps in order), each row's last step marked as a cut."""
    segment_end = batch["next", "done"].clone()
    segment_end[:, -1] = True
    batch.set(SEGMENT_END_KEY, segment_end)
    return batch.reshape(-1)


def train(config: Config, seed: int, her: bool) -> dict[str, Any]:
    """One TD3 run (with HER or a plain buffer); returns the curve and the frames to ``config.target``."""
    torch.manual_seed(seed)
    env = make_env(config.num_envs, seed)
    transform = env.transform[1]  # the TaskTransform: its relabel re-judges stored transitions
    actor = TensorDictModule(Actor(config.hidden), in_keys=["observation", "goal"], out_keys=["action"])
    critic = TensorDictModule(
        Critic(config.hidden), in_keys=["observation", "goal", "action"], out_keys=["state_action_value"]
    )
    loss = TD3Loss(
        actor, critic, action_spec=Bounded(-MAX_FORCE, MAX_FORCE, shape=(2,)), num_qvalue_nets=2,
        policy_noise=0.2 * MAX_FORCE, noise_clip=0.5 * MAX_FORCE,
    )  # fmt: skip
    loss.make_value_estimator(gamma=config.gamma)
    updater = SoftUpdate(loss, tau=config.tau)
    actor_opt = torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=config.lr)
    critic_opt = torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=config.lr)
    storage = LazyTensorStorage(config.buffer_size)
    if her:
        buffer = HERReplayBuffer(
            reward_fn=transform.relabel, her_ratio=config.her_ratio, strategy="future", goal_key="goal",
            achieved_goal_key=("next", "achieved_goal"), end_key=SEGMENT_END_KEY, storage=storage,
            batch_size=config.batch_size,
        )  # fmt: skip
    else:
        buffer = TensorDictReplayBuffer(storage=storage, batch_size=config.batch_size)

    frames, updates, next_eval = 0, 0, config.eval_every
    curve = [{"frames": 0, "eval_success_rate": evaluate(actor), "seconds": 0.0}]
    frames_to_target = None
    start = time.perf_counter()
    td = env.reset()
    progress = frame_bar(f"{'HER' if her else 'plain'} seed {seed}", config.total_frames)
    while frames < config.total_frames:
        steps = []
        with torch.no_grad():
            for _ in range(config.steps_per_collection):
                if frames < config.warmup_frames:
                    td["action"] = env.action_spec.rand()
                else:
                    actor(td)
                    noise = torch.randn_like(td["action"]) * config.exploration_noise * MAX_FORCE
                    td["action"] = (td["action"] + noise).clamp(-MAX_FORCE, MAX_FORCE)
                out, td = env.step_and_maybe_reset(td)
                steps.append(out)
                frames += config.num_envs
        buffer.extend(mark_rows(torch.stack(steps, dim=1)))
        progress.update(config.num_envs * config.steps_per_collection)
        if frames >= config.warmup_frames:
            for _ in range(config.updates_per_collection):
                sample = buffer.sample()
                critic_opt.zero_grad()
                loss.value_loss(sample)[0].backward()
                critic_opt.step()
                if updates % config.policy_delay == 0:  # TD3's delayed actor and target updates
                    actor_opt.zero_grad()
                    loss.actor_loss(sample)[0].backward()
                    actor_opt.step()
                    updater.step()
                updates += 1
        if frames >= next_eval or frames >= config.total_frames:
            next_eval += config.eval_every
            rate = evaluate(actor)
            curve.append({"frames": frames, "eval_success_rate": rate, "seconds": time.perf_counter() - start})
            progress.set_postfix(success=f"{rate:.2f}")
            if rate >= config.target:
                frames_to_target = frames
                break
    progress.close()
    return {
        "variant": "her" if her else "plain",
        "seed": seed,
        "frames_to_target": frames_to_target,
        "total_frames": frames,
        "updates": updates,
        "seconds": time.perf_counter() - start,
        "final_success_rate": curve[-1]["eval_success_rate"],
        "curve": curve,
    }


def plot(experiment: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    colors = {"her": "tab:blue", "plain": "tab:orange"}
    labels = {"her": "TD3 + HER", "plain": "TD3, plain replay"}
    for variant, record in experiment["variants"].items():
        for i, run in enumerate(record["runs"]):
            xs = [p["frames"] for p in run["curve"]]
            ys = [p["eval_success_rate"] for p in run["curve"]]
            ax.plot(xs, ys, color=colors[variant], alpha=0.8, label=labels[variant] if i == 0 else None)
            if run["frames_to_target"] is not None:
                ax.plot([run["frames_to_target"]], [ys[-1]], "o", color=colors[variant])
    ax.axhline(experiment["config"]["target"], color="gray", linestyle="--", linewidth=1)
    ax.set_xlabel("environment frames")
    ax.set_ylabel("evaluation success rate")
    ax.set_ylim(-0.02, 1.02)
    target = experiment["config"]["target"]
    ax.set_title(f"Point-mass goal reaching, TD3 ± HER ({EVAL_ENVS} fixed goals; dot: {target:.0%} reached)")
    ax.legend(loc="upper left")
    fig.tight_layout()
    mark_short_series(fig)  # a --quick run's few points stay visible
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a tiny run (seconds) that runs every code path")
    add_output_argument(parser, Path("runs/goal_reaching"), "directory for the JSON and PNG")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds of each variant")
    parser.add_argument(
        "--variants", nargs="+", default=["her", "plain"], choices=["her", "plain"], metavar="NAME",
        help="her and/or plain: TD3 with and without HER",
    )  # fmt: skip
    parser.add_argument("--frames", type=int, help=f"frame budget per run {default_text(Config.total_frames)}")
    parser.add_argument("--target", type=float, help=f"stop a run at this success rate {default_text(Config.target)}")
    args = parser.parse_args()
    args.output = output_folder(parser, args, Path("runs/goal_reaching"))
    torch.set_num_threads(1)
    config = QUICK if args.quick else Config()
    if args.frames is not None:
        config = replace(config, total_frames=args.frames)
    if args.target is not None:
        config = replace(config, target=args.target)
    seeds = args.seeds[:1] if args.quick else args.seeds
    experiment: dict[str, Any] = {
        "config": asdict(config),
        "task": "sparse: -1 per step, 0 on reaching the goal (radius 0.1), success ends the episode",
        "env": {"max_force": MAX_FORCE, "max_steps": MAX_STEPS, "goal_box": [-0.8, 0.8], "eval_envs": EVAL_ENVS},
        "machine": {"load_1min": os.getloadavg()[0], "cpus": os.cpu_count()},
        "command": "python examples/goal_reaching.py" + (" --quick" if args.quick else ""),
        "variants": {},
    }
    start = time.perf_counter()
    for variant in args.variants:
        runs = []
        for seed in seeds:
            run = train(config, seed, her=variant == "her")
            runs.append(run)
            reached = run["frames_to_target"]
            what = f"after {reached:,} frames" if reached is not None else "not reached"
            print(
                f"{variant}, seed {seed}: {config.target:.0%} {what}; final success rate "
                f"{run['final_success_rate']:.3f} after {run['total_frames']:,} frames ({duration(run['seconds'])})",
                flush=True,
            )
        experiment["variants"][variant] = {"runs": runs, "frames_to_target": [r["frames_to_target"] for r in runs]}
    experiment["total_seconds"] = time.perf_counter() - start
    json_path, png_path = args.output / "goal_reaching.json", args.output / "goal_reaching.png"
    json_path.write_text(json.dumps(experiment, indent=1))
    plot(experiment, png_path)
    print(f"wrote {json_path} and {png_path} ({experiment['total_seconds']:.0f} s)")


if __name__ == "__main__":
    from _cli import add_output_argument, default_text, make_parser, output_folder, quiet_torchrl

    quiet_torchrl()
    main()
