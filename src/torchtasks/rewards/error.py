"""Rewards on state and action errors: absolute, quadratic, exp-quadratic and scaled exp-quadratic."""

from __future__ import annotations

import math

import torch
from torch import nn

from torchtasks._checks import as_constant, cast_like, check_finite_scalar
from torchtasks.rewards.base import RewardFunction, row_dot, row_sum
from torchtasks.spaces import Box

__all__ = [
    "AbsoluteErrorReward",
    "ExpQuadraticErrorReward",
    "QuadraticErrorReward",
    "ScaledExpQuadraticErrorReward",
]

_EIGENVALUE_TOLERANCE = 1e-10


def _weight_matrix(value: object, name: str) -> torch.Tensor:
    """Validate a PSD weight given as a full ``n x n`` matrix or a vector (its diagonal)."""
    weight = as_constant(value, name, ndim=(1, 2))
    if weight.ndim == 2:
        if weight.shape[0] != weight.shape[1]:
            raise ValueError(f"{name} must be a square n x n matrix or a vector, got shape {tuple(weight.shape)}")
        if not torch.isfinite(weight).all():
            raise ValueError(f"{name} must be finite, got {weight.tolist()}")
        if weight.numel():
            symmetric = 0.5 * (weight + weight.T)
            smallest = torch.linalg.eigvalsh(symmetric).min()
            scale = max(1.0, float(weight.abs().max()))
            if smallest < -_EIGENVALUE_TOLERANCE * scale:
                raise ValueError(
                    f"{name} must be positive semi-definite, got a matrix with eigenvalue {float(smallest):.6g}"
                )
    else:
        if not torch.isfinite(weight).all():
            raise ValueError(f"{name} must be finite, got {weight.tolist()}")
        if (weight < 0).any():
            raise ValueError(f"{name} (a diagonal) must be non-negative, got {weight.tolist()}")
    return weight


def _weight_vector(value: object, name: str) -> torch.Tensor:
    """Validate a non-negative weight vector."""
    weight = as_constant(value, name, ndim=(1,))
    if not torch.isfinite(weight).all() or (weight < 0).any():
        raise ValueError(f"{name} must be finite and non-negative, got {weight.tolist()}")
    return weight


def quadratic_form(weight: torch.Tensor, error: torch.Tensor, *, diagonal: bool | None = None) -> torch.Tensor:
    """Return ``errorᵀ W error`` per row, for a full matrix or a diagonal vector ``W``.

    ``W`` is shared by all rows (``[n]`` or ``[n, n]``) or given per row (``[*B, n]`` or ``[*B, n, n]``: per-frame
    values, as offline recomputation swaps them in). ``diagonal`` says which a weight with leading dims holds;
    ``None``: a 1-d weight is a diagonal, a 2-d one a matrix.

    Example:
        >>> import torch
        >>> error = torch.tensor([[1.0, 2.0], [1.0, 0.0]])
        >>> quadratic_form(torch.tensor([1.0, 0.5]), error)
        tensor([3., 1.])
        >>> quadratic_form(torch.tensor([[1.0, 0.5], [4.0, 0.0]]), error, diagonal=True)  # one diagonal per row
        tensor([3., 4.])
    """
    weight = cast_like(weight, error)
    if weight.ndim == 1 or diagonal:
        return row_dot(error * error, weight)
    # Σ_ij e_i W_ij e_j as one row sum of n² products (not (e @ W) · e: a matrix product rounds by batch shape)
    return row_sum((error.unsqueeze(-1) * weight * error.unsqueeze(-2)).flatten(-2))


class _QuadraticCost(RewardFunction):
    """Shared part of the quadratic rewards: validated ``Q``/``R`` and the cost ``eᵀQe + aᵀRa``."""

    def __init__(self, Q: object, R: object | None = None, *, learnable: bool = False) -> None:
        super().__init__()
        self._register_constant("Q", Q, learnable, check=_weight_matrix)
        if R is None:
            self.R = None
            self.uses_action = False
        else:
            self._register_constant("R", R, learnable, check=_weight_matrix)
        # whether Q and R are diagonals: a per-frame value swapped in offline has leading dims beyond that
        self._diagonal_q = self.Q.ndim == 1
        self._diagonal_r = self.R is not None and self.R.ndim == 1

    @property
    def state_size(self) -> int:
        """Size of the state error this reward expects."""
        return self.Q.shape[0]

    @property
    def action_size(self) -> int:
        """Size of the action error this reward expects (0 without ``R``)."""
        return 0 if self.R is None else self.R.shape[0]

    def cost(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        """Return ``e_sᵀ Q e_s + e_aᵀ R e_a`` per environment."""
        self._check_inputs(error_state, error_action, self.state_size, self.action_size)
        return self._cost(error_state, error_action)

    def _cost(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        cost = quadratic_form(self.Q, error_state, diagonal=self._diagonal_q)
        if self.uses_action:
            cost = cost + quadratic_form(self.R, error_action, diagonal=self._diagonal_r)
        return cost

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        self._check_inputs(error_state, error_action, self.state_size, self.action_size)
        return self._value(error_state, error_action)


class QuadraticErrorReward(_QuadraticCost):
    """Negative quadratic cost of state and action errors: ``-(e_sᵀ Q e_s + e_aᵀ R e_a)``.

    Args:
        Q: state weight, a positive semi-definite ``n x n`` matrix or a non-negative vector
            (the diagonal).
        R: action weight, ``m x m`` matrix or vector; ``None`` for no action cost.
        learnable: make ``Q`` and ``R`` ``nn.Parameter``\\ s (reward learning) instead of buffers.

    Pyrado name: ``QuadrErrRewFcn`` (whose docstring wrongly promised an exponential).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> reward = QuadraticErrorReward(Q=torch.eye(2), R=[0.1])
        >>> reward(torch.tensor([[1.0, 2.0]]), torch.tensor([[3.0]]))
        tensor([-5.9000])
    """

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return -self._cost(error_state, error_action)


class ExpQuadraticErrorReward(_QuadraticCost):
    """Exponentiated negative quadratic cost: ``exp(-(e_sᵀ Q e_s + e_aᵀ R e_a))``, in ``(0, 1]``.

    Args:
        Q: state weight (``n x n`` PSD matrix or non-negative diagonal vector).
        R: action weight (``m x m`` or vector); ``None`` for no action cost.
        learnable: make ``Q`` and ``R`` trainable parameters.

    Pyrado name: ``ExpQuadrErrRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ExpQuadraticErrorReward
        >>> ExpQuadraticErrorReward(Q=[1.0], R=None)(torch.zeros(3, 1), None)
        tensor([1., 1., 1.])
    """

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return torch.exp(-self._cost(error_state, error_action))


class ScaledExpQuadraticErrorReward(_QuadraticCost):
    """Exp-quadratic reward scaled so that the worst-case error of the boxes gives ``min_reward``.

    ``exp(-c_max · (e_sᵀ Q e_s + e_aᵀ R e_a))`` with ``c_max = -ln(min_reward) / C_max`` and
    ``C_max = s_maxᵀ Q s_max + a_maxᵀ R a_max``, where ``s_max``/``a_max`` are the largest
    absolute bounds of ``state_space``/``action_space``. Infinite bounds give ``c_max = 0``
    (reward ≡ 1); entries with zero weight do not count.

    Args:
        Q, R: weights as for :class:`QuadraticErrorReward` (``R`` is required here).
        state_space, action_space: the boxes whose worst case defines the scale.
        min_reward: reward at the worst-case error, in the open interval ``(0, 1)``. Unlike
            Pyrado (which reverted to 1e-4 at every task reset), the value given here is kept.
        learnable: make ``Q`` and ``R`` trainable parameters (the scale follows them).

    Pyrado name: ``ScaledExpQuadrErrRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ScaledExpQuadraticErrorReward
        >>> from torchtasks.spaces import Box
        >>> reward = ScaledExpQuadraticErrorReward([1.0], [1.0], Box(-2.0, 2.0), Box(-1.0, 1.0), min_reward=0.01)
        >>> reward(torch.tensor([[2.0]]), torch.tensor([[1.0]]))
        tensor([0.0100])
    """

    def __init__(
        self,
        Q: object,
        R: object,
        state_space: Box,
        action_space: Box,
        min_reward: float = 1e-4,
        *,
        learnable: bool = False,
    ) -> None:
        super().__init__(Q, R, learnable=learnable)
        if not isinstance(state_space, Box) or not isinstance(action_space, Box):
            raise TypeError(
                "state_space and action_space must be torchtasks.spaces.Box, got "
                f"{type(state_space).__name__} and {type(action_space).__name__}"
            )
        min_reward = check_finite_scalar(min_reward, "min_reward")
        if not 0.0 < min_reward < 1.0:
            raise ValueError(f"min_reward must lie in the open interval (0, 1), got {min_reward}")
        if state_space.size != self.state_size:
            raise ValueError(f"state_space must have {self.state_size} entries to match Q, got {state_space.size}")
        if action_space.size != self.action_size:
            raise ValueError(f"action_space must have {self.action_size} entries to match R, got {action_space.size}")
        self.min_reward = min_reward
        self.register_buffer("state_bound", state_space.bound_abs_high)
        self.register_buffer("action_bound", action_space.bound_abs_high)
        worst_case = self._worst_case_cost().detach()
        if float(worst_case) == 0.0:
            raise ValueError("the worst-case cost s_maxᵀQs_max + a_maxᵀRa_max is 0: the reward cannot be scaled")
        self.register_buffer("_c_max", -math.log(min_reward) / worst_case)

    def _worst_case_cost(self) -> torch.Tensor:
        """``s_maxᵀQs_max + a_maxᵀRa_max``; infinite where an unbounded entry has a positive weight.

        An entry with zero diagonal weight does not count (a PSD matrix then has a zero row and
        column), so infinite bounds on unweighted entries do not make the scale vanish.
        """

        def bounded_form(weight: torch.Tensor, bound: torch.Tensor) -> torch.Tensor:
            diagonal = weight.diagonal() if weight.ndim == 2 else weight
            unbounded = torch.isinf(bound) & (diagonal > 0)
            finite_bound = torch.where(torch.isinf(bound), torch.zeros_like(bound), bound)
            value = quadratic_form(weight, finite_bound)
            return torch.where(unbounded.any(), torch.full_like(value, math.inf), value)

        return bounded_form(self.Q, self.state_bound) + bounded_form(self.R, self.action_bound)

    @property
    def c_max(self) -> torch.Tensor:
        """The scale ``-ln(min_reward) / C_max`` (0 for infinite bounds); follows learnable weights."""
        if isinstance(self.Q, nn.Parameter):
            return -math.log(self.min_reward) / self._worst_case_cost()
        return self._c_max

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        scale = cast_like(self.c_max, error_state)
        return torch.exp(-scale * self._cost(error_state, error_action))


class AbsoluteErrorReward(RewardFunction):
    """Negative weighted absolute error: ``-(|e_s| · q + |e_a| · r)``.

    Args:
        q: non-negative state weights, a vector of ``n``.
        r: non-negative action weights, a vector of ``m``; ``None`` for no action cost.
        learnable: make ``q`` and ``r`` trainable parameters.

    Pyrado name: ``AbsErrRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import AbsoluteErrorReward
        >>> AbsoluteErrorReward(q=[1.0, 2.0], r=[0.5])(torch.tensor([[1.0, -1.0]]), torch.tensor([[-2.0]]))
        tensor([-4.])
    """

    def __init__(self, q: object, r: object | None = None, *, learnable: bool = False) -> None:
        super().__init__()
        self._register_constant("q", q, learnable, check=_weight_vector)
        if r is None:
            self.r = None
            self.uses_action = False
        else:
            self._register_constant("r", r, learnable, check=_weight_vector)

    @property
    def state_size(self) -> int:
        """Size of the state error this reward expects."""
        return self.q.shape[0]

    @property
    def action_size(self) -> int:
        """Size of the action error this reward expects (0 without ``r``)."""
        return 0 if self.r is None else self.r.shape[0]

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        self._check_inputs(error_state, error_action, self.state_size, self.action_size)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        value = row_dot(error_state.abs(), cast_like(self.q, error_state))
        if self.uses_action:
            value = value + row_dot(error_action.abs(), cast_like(self.r, error_action))
        return -value
