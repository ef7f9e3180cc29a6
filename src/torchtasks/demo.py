"""The ``torchtasks demo``: a swing-up task on the batched torch pendulum inside a TorchRL Collector.

A classical controller (energy pumping, then a PD controller near the top; no learning) drives 64
pendulums; the task decides rewards, successes and episode ends. The demo prints per-term episode
rewards, success/failure/truncation counts and frames per second, and saves a PNG plot of the
per-term rewards over time.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.transforms import TaskTransform

__all__ = ["DemoResult", "SwingUpController", "make_swing_up_env", "run_demo"]

TERMS = ("track", "effort", "final")


class SwingUpController(nn.Module):
    """Energy-pumping swing-up with a PD controller near the top, for :class:`PendulumEnv` (θ = 0 upright).

    With ``θ̈ = a·sin θ + b·u`` the energy ``E = θ̇²/2 + a·cos θ`` reaches its upright value ``a``
    under ``u = k·θ̇·(a - E)``; within ``switch_angle`` of the top, ``u = -kp·θ - kd·θ̇``.

    Example:
        >>> import torch
        >>> SwingUpController()(torch.tensor([[0.1, 0.0]]))
        tensor([[-1.0000]])
    """

    def __init__(
        self,
        gain: float = 1.0,
        kp: float = 10.0,
        kd: float = 2.0,
        switch_angle: float = 0.3,
        max_torque: float = 2.0,
        gravity_term: float = 15.0,
    ) -> None:
        super().__init__()
        self.gain, self.kp, self.kd = gain, kp, kd
        self.switch_angle, self.max_torque, self.gravity_term = switch_angle, max_torque, gravity_term

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        angle = torch.remainder(observation[..., 0] + math.pi, 2 * math.pi) - math.pi
        speed = observation[..., 1]
        energy = 0.5 * speed**2 + self.gravity_term * torch.cos(angle)
        pump = self.gain * speed * (self.gravity_term - energy)
        # a push from rest at the bottom, where the pumping law gives nothing
        pump = torch.where(speed.abs() < 1e-3, torch.full_like(pump, self.max_torque), pump)
        hold = -self.kp * angle - self.kd * speed
        torque = torch.where(angle.abs() < self.switch_angle, hold, pump)
        return torque.clamp(-self.max_torque, self.max_torque).unsqueeze(-1)


def make_swing_up_env(num_envs: int = 64, max_steps: int = 200, seed: int = 0) -> TransformedEnv:
    """Return ``PendulumEnv`` + ``StepCounter`` + ``TaskTransform(swing_up_task())`` + ``RewardSum``.

    Example:
        >>> env = make_swing_up_env(num_envs=2, max_steps=5)
        >>> env.rollout(3)["next", "task_reward", "track"].shape
        torch.Size([2, 3, 1])
    """
    return TransformedEnv(
        PendulumEnv(batch_size=[num_envs], seed=seed),
        Compose(StepCounter(max_steps), TaskTransform(swing_up_task()), RewardSum()),
    )


@dataclass
class DemoResult:
    """What the demo measured."""

    frames: int
    seconds: float
    episodes: int
    successes: int
    failures: int
    truncations: int
    episode_terms: dict[str, float]
    term_curves: dict[str, list[float]] = field(default_factory=dict)
    plot_path: Path | None = None

    @property
    def frames_per_second(self) -> float:
        """Collected frames per second of wall-clock time."""
        return self.frames / self.seconds


def run_demo(
    total_frames: int = 64_000,
    num_envs: int = 64,
    frames_per_batch: int = 3_200,
    output_dir: str | Path = ".",
    progress: bool = True,
    seed: int = 0,
) -> DemoResult:
    """Collect ``total_frames`` with the swing-up controller and summarise the task's outputs.

    Example:
        >>> result = run_demo(total_frames=640, num_envs=8, frames_per_batch=320, output_dir=None, progress=False)
        >>> result.frames
        640
    """
    torch.manual_seed(seed)
    env = make_swing_up_env(num_envs=num_envs, seed=seed)
    policy = TensorDictModule(SwingUpController(), in_keys=["observation"], out_keys=["action"])
    collector = Collector(
        env, policy, frames_per_batch=frames_per_batch, total_frames=total_frames, auto_register_policy_transforms=False
    )
    sums = dict.fromkeys(TERMS, 0.0)
    curves: dict[str, list[float]] = {name: [] for name in TERMS}
    frames = episodes = successes = failures = truncations = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total_frames, unit="frames", desc="swing-up demo")
    start = time.perf_counter()
    for batch in collector:
        nxt = batch["next"]
        ended = nxt["done"]
        episodes += int(ended.sum())
        successes += int(nxt["success"].sum())
        failures += int(nxt["failure"].sum())
        truncations += int((nxt["truncated"] & ~nxt["success"] & ~nxt["failure"]).sum())
        for name in TERMS:
            sums[name] += float(nxt["task_reward", f"episode_{name}"][ended].sum())
            curves[name].append(float(nxt["task_reward", name].mean()))
        frames += batch.numel()
        if bar is not None:
            bar.update(batch.numel())
    seconds = time.perf_counter() - start
    collector.shutdown()
    if bar is not None:
        bar.close()
    episode_terms = {name: value / max(episodes, 1) for name, value in sums.items()}
    result = DemoResult(frames, seconds, episodes, successes, failures, truncations, episode_terms, curves)
    if output_dir is not None:
        result.plot_path = _plot(curves, frames_per_batch, Path(output_dir) / "torchtasks_demo.png")
    return result


def _plot(curves: dict[str, list[float]], frames_per_batch: int, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    figure, axis = plt.subplots(figsize=(7, 4))
    for name, values in curves.items():
        axis.plot([frames_per_batch * (i + 1) for i in range(len(values))], values, label=name)
    axis.set_xlabel("frames collected")
    axis.set_ylabel("mean reward per step")
    axis.set_title("Swing-up task: per-term rewards")
    axis.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def format_result(result: DemoResult) -> str:
    """Return the demo's summary as a Markdown table."""
    rows = [
        ("frames", f"{result.frames}"),
        ("frames/s", f"{result.frames_per_second:,.0f}"),
        ("episodes ended", f"{result.episodes}"),
        ("successes", f"{result.successes}"),
        ("failures", f"{result.failures}"),
        ("truncations", f"{result.truncations}"),
    ]
    rows += [(f"mean episode reward: {name}", f"{value:+.3f}") for name, value in result.episode_terms.items()]
    if result.plot_path is not None:
        rows.append(("plot", str(result.plot_path)))
    width = max(len(name) for name, _ in rows)
    lines = [f"| {'quantity':<{width}} | value |", f"|{'-' * (width + 2)}|-------|"]
    lines += [f"| {name:<{width}} | {value} |" for name, value in rows]
    return "\n".join(lines)
