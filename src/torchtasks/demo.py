"""The ``torchtasks demo``: a swing-up task on the batched torch pendulum inside a TorchRL Collector.

A classical controller (energy pumping, then a PD controller near the top; no learning) drives 64
pendulums; the task decides rewards, successes and episode ends. Gaussian noise is added to the
controller's torque, decaying linearly from ``noise`` to 0 over the first three quarters of the run
(like an agent's exploration noise), so the run shows the task's signals follow the quality of
control: episode return and success rate rise, the per-term returns move apart.

The demo prints per-term episode returns, success/failure/truncation counts and frames per second,
and writes to ``output_dir`` (default ``runs/demo``, relative to the current folder):

- ``torchtasks_demo.json``: the summary and, per collected batch, the frames collected so far, the
  noise, the number of finished episodes and their mean return, success rate and per-term returns;
- ``torchtasks_demo.png`` (needs matplotlib, the ``plot`` extra): those curves against frames
  collected, in three panels (episode return; success rate and noise; per-term episode returns).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.stats import episode_statistics
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
    """What the demo measured.

    ``curves`` holds one value per collected batch: ``"frames"`` (collected so far), ``"noise"`` (the
    standard deviation of the action noise during the batch), ``"episodes"`` (finished in the batch),
    and ``"return"``, ``"success_rate"`` and ``"episode_<term>"``: :func:`~torchtasks.stats.episode_statistics`
    of the last ``max_steps`` steps (one episode length): the success rate of the episodes that ended
    in them, the returns of those that also started in them; ``None`` before the first ``max_steps``
    steps (when only quick successes can have finished) and when no episode finished. The totals
    (``episodes``, ``successes``, ``failures``, ``truncations``, ``episode_terms``) are the same
    statistics over the whole run.
    """

    frames: int
    seconds: float
    episodes: int
    successes: int
    failures: int
    truncations: int
    episode_terms: dict[str, float]
    curves: dict[str, list[float | None]] = field(default_factory=dict)
    noise: float = 0.0
    metrics_path: Path | None = None
    plot_path: Path | None = None
    plot_note: str | None = None

    @property
    def frames_per_second(self) -> float:
        """Collected frames per second of wall-clock time."""
        return self.frames / self.seconds


class _NoisyTorque(nn.Module):
    """The controller's torque plus Gaussian noise of standard deviation ``scale`` (set between batches), clipped."""

    def __init__(self, controller: SwingUpController) -> None:
        super().__init__()
        self.controller = controller
        self.scale = 0.0

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        torque = self.controller(observation)
        if self.scale > 0:
            torque = torque + self.scale * torch.randn_like(torque)
        limit = self.controller.max_torque
        return torque.clamp(-limit, limit)


#: the fraction of the run over which the action noise decays to 0 (the rest runs noise-free)
NOISE_DECAY_FRACTION = 0.75

#: the episode length of the demo's env (``StepCounter(MAX_STEPS)``: truncation)
MAX_STEPS = 200


def run_demo(
    total_frames: int = 64_000,
    num_envs: int = 64,
    frames_per_batch: int = 1_600,
    output_dir: str | Path | None = "runs/demo",
    progress: bool = True,
    seed: int = 0,
    noise: float = 5.0,
) -> DemoResult:
    """Collect ``total_frames`` with the noisy swing-up controller and summarise the task's outputs.

    ``noise`` is the standard deviation of the torque noise at the start (the torque limit is 2); it
    decays linearly to 0 at ``NOISE_DECAY_FRACTION`` of the run. The files go to ``output_dir``
    (created if needed; ``None``: nothing is written).

    Example:
        >>> result = run_demo(total_frames=640, num_envs=8, frames_per_batch=320, output_dir=None, progress=False)
        >>> result.frames, len(result.curves["return"])
        (640, 2)
    """
    torch.manual_seed(seed)
    env = make_swing_up_env(num_envs=num_envs, max_steps=MAX_STEPS, seed=seed)
    actor = _NoisyTorque(SwingUpController())
    policy = TensorDictModule(actor, in_keys=["observation"], out_keys=["action"])
    collector = Collector(
        env, policy, frames_per_batch=frames_per_batch, total_frames=total_frames, auto_register_policy_transforms=False
    )
    # every batch ([envs, time]); the rolling statistics join the last `window_batches` of them along time
    batches: list[TensorDictBase] = []
    window_batches = max(1, math.ceil(MAX_STEPS * num_envs / frames_per_batch))
    keys = ("frames", "noise", "episodes", "return", "success_rate", *(f"episode_{name}" for name in TERMS))
    curves: dict[str, list[float | None]] = {key: [] for key in keys}
    frames = 0

    def noise_at(frames_done: int) -> float:
        return noise * max(0.0, 1.0 - frames_done / (NOISE_DECAY_FRACTION * total_frames))

    bar = None
    if progress:
        from tqdm import tqdm

        # unit_scale: 43.6k frame/s; disable=None: shown on a terminal only (not as \r-updates in a log file)
        bar = tqdm(total=total_frames, unit="frame", unit_scale=True, desc="swing-up demo", disable=None)
    actor.scale = noise_at(0)
    start = time.perf_counter()
    for batch in collector:
        scale = actor.scale
        batches.append(batch)
        ended = int(batch["next", "done"].sum())
        frames += batch.numel()
        # rolling means: the episodes that ended in the last MAX_STEPS steps (one episode length)
        window = batches[-window_batches:]
        rolling = episode_statistics(torch.cat(window, dim=-1)) if len(window) == window_batches else {}

        curves["frames"].append(frames)
        curves["noise"].append(scale)
        curves["episodes"].append(ended)
        curves["return"].append(rolling.get("return_mean"))
        curves["success_rate"].append(rolling.get("success_rate"))
        for name in TERMS:
            curves[f"episode_{name}"].append(rolling.get(f"return_mean/{name}"))
        actor.scale = noise_at(frames)
        if bar is not None:
            rate = curves["success_rate"][-1]
            bar.set_postfix(noise=f"{scale:.1f}", success="-" if rate is None else f"{rate:.0%}", refresh=False)
            bar.update(batch.numel())
    seconds = time.perf_counter() - start
    collector.shutdown()
    if bar is not None:
        bar.close()
    # the whole run's episodes (the demo keeps its frames: a few MB), from the task's own flags and terms
    totals = episode_statistics(torch.cat(batches, dim=-1))
    episodes = int(totals["episodes"])
    successes, failures, truncations = (
        round(totals.get(rate, 0.0) * episodes) for rate in ("success_rate", "failure_rate", "timeout_rate")
    )
    episode_terms = {name: totals.get(f"return_mean/{name}", math.nan) for name in TERMS}
    result = DemoResult(frames, seconds, episodes, successes, failures, truncations, episode_terms, curves, noise)
    if output_dir is not None:
        _write_outputs(result, Path(output_dir))
    return result


def _write_outputs(result: DemoResult, folder: Path) -> None:
    """Write ``torchtasks_demo.json`` and, with matplotlib, ``torchtasks_demo.png`` into ``folder``."""
    import json

    folder.mkdir(parents=True, exist_ok=True)
    summary = {
        "frames": result.frames,
        "seconds": result.seconds,
        "frames_per_second": result.frames_per_second,
        "episodes": result.episodes,
        "successes": result.successes,
        "failures": result.failures,
        "truncations": result.truncations,
        "episode_terms": result.episode_terms,
        "noise": {"start": result.noise, "decay_fraction": NOISE_DECAY_FRACTION},
        "max_steps": MAX_STEPS,
    }
    result.metrics_path = folder / "torchtasks_demo.json"
    result.metrics_path.write_text(json.dumps({"summary": summary, "curves": result.curves}, indent=1) + "\n")
    try:
        from matplotlib.figure import Figure
    except ImportError:
        from torchtasks._optional import install_hint

        result.plot_note = f"no plot: matplotlib is not installed ({install_hint('plot')} for torchtasks_demo.png)"
        return
    result.plot_path = _plot(result, Figure, folder / "torchtasks_demo.png")


def _plot(result: DemoResult, figure_class: type, path: Path) -> Path:
    """Three panels against frames collected: episode return, success rate (and noise), per-term returns."""

    def values(key: str) -> list[float]:
        return [math.nan if value is None else value for value in result.curves[key]]

    from torchtasks._plotting import mark_short_series

    frames = result.curves["frames"]
    figure = figure_class(figsize=(8, 9), layout="constrained")
    axes = figure.subplots(3, 1, sharex=True)

    axes[0].plot(frames, values("return"), color="tab:blue", linewidth=2)
    axes[0].set_ylabel("mean episode return")
    axes[0].set_title("Episode return (task reward + final reward)")

    axes[1].plot(frames, values("success_rate"), color="tab:green", linewidth=2, label="success rate")
    axes[1].set_ylim(-0.05, 1.05)
    axes[1].set_ylabel("success rate")
    axes[1].set_title("Success rate, and the controller's action noise")
    noise_axis = axes[1].twinx()
    noise_axis.plot(frames, values("noise"), color="tab:gray", linestyle="--", label="action noise σ (right axis)")
    noise_axis.set_ylabel("action noise σ (torque)", color="tab:gray")
    noise_axis.set_ylim(bottom=0)
    handles = axes[1].get_legend_handles_labels()[0] + noise_axis.get_legend_handles_labels()[0]
    axes[1].legend(handles=handles, loc="lower right")

    axes[2].plot(frames, values("episode_track"), color="tab:red", linewidth=2, label="track (angle, speed error)")
    axes[2].plot(frames, values("episode_final"), color="tab:orange", linewidth=2, label="final (success bonus)")
    axes[2].axhline(0.0, color="black", linewidth=0.5)
    axes[2].set_ylabel("mean episode return per term")
    axes[2].set_title("Per-term episode returns")
    axes[2].set_xlabel("frames collected")
    effort_axis = axes[2].twinx()
    effort_axis.plot(frames, values("episode_effort"), color="tab:purple", linewidth=2, label="effort (right axis)")
    effort_axis.set_ylabel("effort (torque cost)", color="tab:purple")
    handles = axes[2].get_legend_handles_labels()[0] + effort_axis.get_legend_handles_labels()[0]
    axes[2].legend(handles=handles, loc="lower right")

    for axis in axes:
        axis.grid(alpha=0.3)
    figure.suptitle(
        f"torchtasks demo: swing-up task, {result.frames:,} frames\n"
        f"means over the episodes finished in the last {MAX_STEPS} steps (one episode length)"
    )
    mark_short_series(figure)  # a --quick run's few points stay visible
    figure.savefig(path, dpi=100)
    return path


def format_result(result: DemoResult) -> str:
    """Return the demo's summary as a Markdown table."""
    rows = [
        ("frames", f"{result.frames:,}"),
        ("frames/s", f"{result.frames_per_second:,.0f}"),
        ("action noise σ", f"{result.noise:g} → 0"),
        ("episodes ended", f"{result.episodes:,}"),
        ("successes", f"{result.successes:,}"),
        ("failures", f"{result.failures:,}"),
        ("truncations", f"{result.truncations:,}"),
    ]
    rows += [(f"mean episode reward: {name}", f"{value:+,.3f}") for name, value in result.episode_terms.items()]
    width = max(len(name) for name, _ in rows)
    value_width = max(len("value"), *(len(value) for _, value in rows))
    lines = [
        f"| {'quantity':<{width}} | {'value':>{value_width}} |",
        f"|{'-' * (width + 2)}|{'-' * (value_width + 1)}:|",
    ]
    lines += [f"| {name:<{width}} | {value:>{value_width}} |" for name, value in rows]
    return "\n".join(lines)
