"""Hand-fused torch functions of the benchmarked tasks: the same maths, no TensorDict, no task objects.

They are the limit a batched task implementation can approach: plain tensors in, plain tensors out.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchtasks.bench.cases import BenchConfig

__all__ = ["FusedConstants", "fused_parallel", "fused_sequential", "fused_t1", "fused_t1_lean"]


@dataclass
class FusedConstants:
    """Constants of the fused functions, already in the state's dtype."""

    goals: torch.Tensor  # [K, n]
    q: torch.Tensor  # [n]
    r: torch.Tensor  # [m]
    bound: torch.Tensor  # 0-d
    threshold: torch.Tensor  # 0-d
    factor: torch.Tensor  # 0-d

    @classmethod
    def of(cls, config: BenchConfig, dtype: torch.dtype = torch.float32) -> FusedConstants:
        goals = torch.tensor([[g] * config.state_size for g in config.goals], dtype=dtype)
        return cls(
            goals=goals,
            q=config.q().to(dtype),
            r=config.r().to(dtype),
            bound=torch.tensor(config.bound, dtype=dtype),
            threshold=torch.tensor(config.threshold, dtype=dtype),
            factor=torch.tensor(config.factor, dtype=dtype),
        )


def _final(failure: torch.Tensor, success: torch.Tensor, factor: torch.Tensor) -> torch.Tensor:
    zero = torch.zeros((), dtype=factor.dtype)
    return torch.where(failure, -factor, torch.where(success, factor, zero))


def fused_t1(
    c: FusedConstants, state: torch.Tensor, action: torch.Tensor, truncated: torch.Tensor, paid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """T1 in one function: ``(reward, done, paid)``."""
    error = c.goals[0] - state
    reward = -((error * error * c.q).sum(-1) + (action * action * c.r).sum(-1))
    success = torch.linalg.vector_norm(error, dim=-1) < c.threshold
    failure = (state.abs() > c.bound).any(-1) | torch.isnan(state).any(-1)
    done = success | failure | truncated
    final = torch.where(done & ~paid, _final(failure, success, c.factor), torch.zeros((), dtype=reward.dtype))
    return reward + final, done, paid | done


def fused_t1_lean(
    c: FusedConstants, state: torch.Tensor, action: torch.Tensor, truncated: torch.Tensor, paid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """T1 with the op choices torchtasks makes (mat-vec quadratic forms, bounds by clamp + count): the lean floor.

    The same maths as :func:`fused_t1`; on the CPU ``(e * e) @ q`` beats ``(e * e * q).sum(-1)`` and a
    clamp-and-count bounds check beats bool ``any`` reductions over a short last dim.
    """
    error = c.goals[0] - state
    reward = -((error * error) @ c.q + (action * action) @ c.r)
    success = torch.linalg.vector_norm(error, dim=-1) < c.threshold
    failure = torch.clamp(state, -c.bound, c.bound).ne(state).count_nonzero(dim=-1) != 0
    done = success | failure | truncated
    final = torch.where(done & ~paid, _final(failure, success, c.factor), torch.zeros((), dtype=reward.dtype))
    return reward + final, done, paid | done


def _sub_tasks(
    c: FusedConstants, state: torch.Tensor, action: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    error = c.goals - state.unsqueeze(-2)  # [B, K, n]
    rewards = -((error * error * c.q).sum(-1) + (action * action * c.r).sum(-1, keepdim=True))
    success = torch.linalg.vector_norm(error, dim=-1) < c.threshold
    failure = ((state.abs() > c.bound).any(-1) | torch.isnan(state).any(-1)).unsqueeze(-1).expand_as(success)
    return rewards, success, failure


def fused_parallel(
    c: FusedConstants,
    state: torch.Tensor,
    action: torch.Tensor,
    truncated: torch.Tensor,
    succeeded: torch.Tensor,
    failed: torch.Tensor,
    paid: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """T2 in one function: ``(reward, done, succeeded, failed, paid)`` with ``[B, K]`` bookkeeping."""
    rewards, success, failure = _sub_tasks(c, state, action)
    active = ~(succeeded | failed)
    zero = torch.zeros((), dtype=rewards.dtype)
    newly = active & (success | failure)
    succeeded = succeeded | (newly & success)
    failed = failed | (newly & ~success)
    values = _final(failure, success, c.factor)
    sub_final = torch.where(newly & ~paid, values, zero)
    paid = paid | newly
    reward = torch.where(active, rewards, zero).sum(-1) + sub_final.sum(-1)
    done = succeeded.all(-1) | failed.any(-1) | truncated
    end_final = torch.where(done.unsqueeze(-1) & ~paid, values, zero).sum(-1)
    paid = paid | done.unsqueeze(-1)
    return reward + end_final, done, succeeded, failed, paid


def fused_sequential(
    c: FusedConstants,
    state: torch.Tensor,
    action: torch.Tensor,
    truncated: torch.Tensor,
    index: torch.Tensor,
    succeeded: torch.Tensor,
    failed: torch.Tensor,
    paid: torch.Tensor,
) -> tuple[torch.Tensor, ...]:
    """T3 in one function: ``(reward, done, index, succeeded, failed, paid)``."""
    rewards, success, failure = _sub_tasks(c, state, action)
    positions = torch.arange(c.goals.shape[0])
    current = positions == index.unsqueeze(-1)
    active = current & ~(succeeded | failed)
    zero = torch.zeros((), dtype=rewards.dtype)
    newly = active & (success | failure)
    succeeded = succeeded | (newly & success)
    failed = failed | (newly & ~success)
    values = _final(failure, success, c.factor)
    sub_final = torch.where(newly & ~paid, values, zero)
    paid = paid | newly
    index = torch.where(newly.any(-1), (index + 1) % c.goals.shape[0], index)
    reward = torch.where(active, rewards, zero).sum(-1) + sub_final.sum(-1)
    done = succeeded.all(-1) | failure[..., 0] | truncated
    end_final = torch.where(done.unsqueeze(-1) & ~paid, values, zero).sum(-1)
    paid = paid | done.unsqueeze(-1)
    return reward + end_final, done, index, succeeded, failed, paid
