"""The demo's statistics equal the same numbers counted from the raw collected flags and RewardSum's sums."""

from __future__ import annotations

import pytest
import torch

import torchtasks.demo as demo


def test_demo_totals_equal_raw_counts(monkeypatch: pytest.MonkeyPatch) -> None:
    """Episodes, outcomes and per-term episode returns of ``run_demo`` against the collected batches themselves."""
    collected: list = []

    class RecordingCollector(demo.Collector):
        def __iter__(self):
            for batch in super().__iter__():
                collected.append(batch.clone())
                yield batch

    monkeypatch.setattr(demo, "Collector", RecordingCollector)
    result = demo.run_demo(total_frames=6_400, num_envs=16, frames_per_batch=800, output_dir=None, progress=False)
    nxt = torch.cat(collected, dim=-1)["next"]
    done = nxt["done"].squeeze(-1)
    assert result.frames == 6_400
    assert result.episodes == int(done.sum()) > 20
    assert result.successes == int((done & nxt["success"].squeeze(-1)).sum()) > 0
    assert result.failures == int((done & nxt["failure"].squeeze(-1)).sum())
    timeouts = done & nxt["truncated"].squeeze(-1) & ~nxt["success"].squeeze(-1)
    assert result.truncations == int(timeouts.sum()) > 0
    # every episode started inside the run (the collector starts from a reset): RewardSum's sums at the last
    # frame are the full episode returns
    for name in demo.TERMS:
        expected = nxt["task_reward", f"episode_{name}"].squeeze(-1)[done].double().mean().item()
        assert result.episode_terms[name] == pytest.approx(expected, rel=1e-5, abs=1e-6)
    # the rolling curves have one value per batch; the success rate is a fraction once the window is full
    assert len(result.curves["success_rate"]) == len(collected)
    rates = [rate for rate in result.curves["success_rate"] if rate is not None]
    assert rates and all(0.0 <= rate <= 1.0 for rate in rates)
