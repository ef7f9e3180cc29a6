"""A Gymnasium MuJoCo locomotion env whose reward comes from a torchtasks task, with per-term logging.

What it shows: :func:`torchtasks.envs.gymnasium_env` builds a TorchRL env of a Gymnasium MuJoCo v5
locomotion env (default ``HalfCheetah-v5``) where ``StepCounter`` + ``TaskTransform`` (the preset's
:func:`~torchtasks.envs.locomotion_task`) + ``RewardSum`` replace Gymnasium's reward and termination.
The task's reward is a compound reward with named terms (``forward``, ``ctrl`` and, depending on the
env, ``contact`` and ``survive``), so every collected frame carries the per-step breakdown
``("task_reward", term)`` and ``RewardSum`` keeps per-term episode sums
``("task_reward", "episode_<term>")``, IsaacLab-style, without any extra code.

The script collects frames with a random policy through a TorchRL ``Collector`` and prints a table
of the per-term rewards: mean per step, mean episode sum of the episodes that ended, and the episode
sum of the episode still running at the last frame (RewardSum's entries, checked here against the
per-step terms summed by hand). Gymnasium's own terms (``info["reward_<term>"]``) are read into the
same frames (an extra info reader on the base env) and compared term by term with the task's.

Run: ``python examples/mujoco_locomotion.py [--quick] [--env Hopper-v5] [--frames N] [--seed N]``
(``--quick``: 300 frames, seconds; used by the tests). Needs the ``mujoco`` extra.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import TransformedEnv

from torchtasks.envs import SUPPORTED_ENV_IDS, Float64InfoReader, gymnasium_env
from torchtasks.transforms import TaskTransform


def task_transform(env: TransformedEnv) -> TaskTransform:
    """The preset's TaskTransform (between StepCounter and RewardSum)."""
    return next(t for t in env.transform if isinstance(t, TaskTransform))


def make_env(env_id: str, seed: int) -> tuple[TransformedEnv, list[str]]:
    """Return the preset env, with Gymnasium's ``info["reward_<term>"]`` read as float64 entries, and the term names."""
    env = gymnasium_env(env_id, seed=seed)
    terms = list(task_transform(env).task.term_names)
    env.base_env.set_info_dict_reader(Float64InfoReader({f"reward_{name}": 1 for name in terms}))
    return env, terms


def collect(env: TransformedEnv, frames: int, frames_per_batch: int) -> TensorDictBase:
    """Collect ``frames`` frames with a random policy; return them as one ``[frames]`` tensordict."""
    collector = Collector(env, None, frames_per_batch=frames_per_batch, total_frames=frames)
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    return torch.cat(batches)


def episode_sums_by_hand(data: TensorDictBase, key: tuple[str, ...]) -> torch.Tensor:
    """Per-episode sums ``[n_episodes]`` of the per-step entry ``key`` (the last episode may be unfinished)."""
    done = data["next", "done"][..., 0].long()
    episode = torch.cumsum(done, 0) - done  # the frame that ends an episode still belongs to it
    values = data["next", key][..., 0].double()
    return torch.zeros(int(episode[-1]) + 1, dtype=torch.float64).index_add_(0, episode, values)


def summarise(data: TensorDictBase, terms: list[str]) -> list[dict[str, float | str]]:
    """One row per breakdown entry: per-step mean, episode sums, and the largest difference to Gymnasium."""
    nxt = data["next"]
    done = nxt["done"][..., 0]
    ends = done.nonzero()[:, 0]
    rows: list[dict[str, float | str]] = []
    for name in terms:  # the preset pays no final reward: its breakdown is the named terms alone
        episode_sum = nxt["task_reward", f"episode_{name}"][..., 0].double()
        # RewardSum's running sums at episode ends and at the last frame equal the per-step terms summed by hand
        by_hand = episode_sums_by_hand(data, ("task_reward", name))
        at_ends = torch.cat([episode_sum[ends], episode_sum[-1:]]) if not done[-1] else episode_sum[ends]
        torch.testing.assert_close(at_ends, by_hand, rtol=1e-4, atol=1e-3)
        row: dict[str, float | str] = {
            "term": name,
            "per_step": nxt["task_reward", name].double().mean().item(),
            "finished": episode_sum[ends].mean().item() if len(ends) else float("nan"),
            "current": episode_sum[-1].item(),
        }
        gym = nxt[f"reward_{name}"][..., 0]  # Gymnasium logs each named term as info["reward_<name>"]
        row["gym_diff"] = (nxt["task_reward", name][..., 0].double() - gym).abs().max().item()
        rows.append(row)
    gym_total = sum(nxt[f"reward_{name}"][..., 0] for name in terms)
    rows.append(
        {
            "term": "reward",
            "per_step": nxt["reward"].double().mean().item(),
            "finished": nxt["episode_reward"][..., 0][ends].double().mean().item() if len(ends) else float("nan"),
            "current": nxt["episode_reward"][-1, 0].item(),
            "gym_diff": (nxt["reward"][..., 0].double() - gym_total).abs().max().item(),
        }
    )
    return rows


def format_table(rows: list[dict[str, float | str]], episodes: int) -> str:
    """Render :func:`summarise` rows as a Markdown table."""
    header = (
        f"| term | mean per step | mean episode sum ({episodes} ended) | current episode sum "
        "| max abs diff to Gymnasium |"
    )
    lines = [header, "|---|---:|---:|---:|---:|"]
    for row in rows:
        finished = "–" if math.isnan(row["finished"]) else f"{row['finished']:+.3f}"  # NaN: none ended
        gym = f"{row['gym_diff']:.1e}" if "gym_diff" in row else "–"
        lines.append(f"| {row['term']} | {row['per_step']:+.4f} | {finished} | {row['current']:+.3f} | {gym} |")
    return "\n".join(lines)


def main(env_id: str = "HalfCheetah-v5", quick: bool = False, frames: int | None = None, seed: int = 0) -> None:
    """Collect with a random policy and print the per-term table and the comparison with Gymnasium."""
    frames = frames or (300 if quick else 5_000)
    frames_per_batch = min(frames, 100 if quick else 1_000)
    torch.manual_seed(seed)
    env, terms = make_env(env_id, seed)
    data = collect(env, frames, frames_per_batch)
    env.close()
    nxt = data["next"]
    episodes = int(nxt["done"].sum())
    print(f"{env_id}: {data.numel()} frames, random policy, {episodes} episode{'' if episodes == 1 else 's'} ended")
    print(f"  failures (unhealthy): {int(nxt['failure'].sum())}, truncations: {int(nxt['truncated'].sum())}")
    print(f"  task reward terms: {', '.join(terms)} (+ the breakdown entries step and final)")
    rows = summarise(data, terms)
    print(format_table(rows, episodes))
    worst = max(row["gym_diff"] for row in rows if "gym_diff" in row)
    print(f"largest difference to Gymnasium's info terms over {data.numel()} steps: {worst:.1e}")
    print("RewardSum episode sums match the per-step terms summed by hand")


if __name__ == "__main__":
    from _cli import default_text, make_parser, quiet_torchrl

    quiet_torchrl()
    parser = make_parser(__doc__)
    parser.add_argument(
        "--env",
        default="HalfCheetah-v5",
        choices=SUPPORTED_ENV_IDS,
        metavar="ID",
        help="one of " + ", ".join(SUPPORTED_ENV_IDS),
    )
    parser.add_argument("--quick", action="store_true", help="300 frames (seconds)")
    parser.add_argument(
        "--frames", type=int, default=None, help=f"frames to collect {default_text(5000, '300 with --quick')}"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    args = parser.parse_args()
    main(args.env, args.quick, args.frames, args.seed)
