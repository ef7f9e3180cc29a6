"""A sum of named reward terms whose values can be logged one by one."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from torchtasks._checks import cast_like, check_finite_scalar, check_input, check_same_batch
from torchtasks._memory import copy_entries, read
from torchtasks.rewards.base import RewardFunction, empty_memory

__all__ = ["CompoundReward"]


class _TermModules(nn.ModuleDict):
    """An ``nn.ModuleDict`` whose keys may be names of ``nn.Module`` attributes (``forward``, ``train``, ...).

    ``nn.ModuleDict`` refuses such keys because it also exposes its entries as attributes; the terms
    of a :class:`CompoundReward` are only looked up by item (``terms[name]``), so a term may be named
    ``forward`` like Gymnasium's ``info["reward_forward"]``. Names are validated by the caller.
    """

    def __setitem__(self, key: str, module: nn.Module) -> None:
        self._modules[key] = module


class _TermWeights(nn.Module):
    """The per-term weights of a :class:`CompoundReward`: one 0-d float64 buffer per weighted term.

    Buffers are put in ``_buffers`` directly, so a term may be named like an ``nn.Module`` attribute
    (``forward``); they are only read by item. ``named_buffers()`` names them ``weights.<term>``.
    """

    def __init__(self, weights: dict[str, float]) -> None:
        super().__init__()
        for name, weight in weights.items():
            self._buffers[name] = torch.tensor(weight, dtype=torch.float64)


class CompoundReward(RewardFunction):
    """Sum of named reward terms, ``Σ_k w_k · term_k(e_s, e_a)``, with the per-term values available.

    Args:
        rewards: a mapping ``name -> reward function`` or a sequence of reward functions (named
            ``term0``, ``term1``, ...). Terms may be stateful (forward velocity): their memory is
            kept under their name.
        weights: optional per-term weights ``{name: weight}`` (finite real numbers; negative ones allowed,
            as IsaacLab's ``RewardTermCfg(weight=...)``), like mjlab's and IsaacLab's reward terms. A term
            without a weight is added as it is (``w = 1``, no multiplication): without ``weights`` the
            reward is the plain sum it always was.

    :meth:`terms` returns the per-term values (stateless terms only); :meth:`step_terms` returns
    them with memory. :class:`~torchtasks.transforms.TaskTransform` logs them. A task checks every
    term against its state and action sizes at construction (:meth:`check_sizes`).

    The breakdown reports **weighted** terms (``w_k · term_k``), as IsaacLab's reward manager logs
    them, so the logged terms still add up to the reward. Each weight is a registered float64 buffer
    named ``weights.<term>`` in the compound (``reward.weights.effort`` for the reward of a
    :class:`~torchtasks.tasks.DesiredStateTask`, as ``task.named_buffers()`` names it): a
    :class:`~torchtasks.transforms.Curriculum` schedules it by that name, IsaacLab's
    ``modify_reward_weight``. To schedule a term that should start at its plain value, give it the
    weight ``1.0``.

    Pyrado name: ``CompoundRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import CompoundReward, ConstantReward, QuadraticErrorReward
        >>> reward = CompoundReward({"track": QuadraticErrorReward([1.0], None), "alive": ConstantReward(1.0)})
        >>> reward(torch.tensor([[2.0]]), None)
        tensor([-3.])
        >>> reward.terms(torch.tensor([[2.0]]), None)
        {'track': tensor([-4.]), 'alive': tensor([1.])}
        >>> weighted = CompoundReward({"track": QuadraticErrorReward([1.0], None), "alive": ConstantReward(1.0)},
        ...                           weights={"track": 0.5})
        >>> weighted.terms(torch.tensor([[2.0]]), None)
        {'track': tensor([-2.]), 'alive': tensor([1.])}
        >>> [name for name, _ in weighted.named_buffers() if name.startswith("weights.")]
        ['weights.track']
    """

    def __init__(
        self,
        rewards: Mapping[str, RewardFunction] | Sequence[RewardFunction],
        weights: Mapping[str, float] | None = None,
    ) -> None:
        super().__init__()
        if isinstance(rewards, Mapping):
            items = list(rewards.items())
        elif isinstance(rewards, Sequence) and not isinstance(rewards, str):
            items = [(f"term{i}", reward) for i, reward in enumerate(rewards)]
        else:
            raise TypeError(f"rewards must be a mapping or a sequence of RewardFunction, got {type(rewards).__name__}")
        if not items:
            raise ValueError("rewards must contain at least one reward function, got an empty collection")
        for name, reward in items:
            if not isinstance(name, str) or not name.isidentifier():
                raise ValueError(f"term names must be identifiers, got {name!r}")
            if not isinstance(reward, RewardFunction):
                raise TypeError(f"term {name!r} must be a RewardFunction, got {type(reward).__name__}")
        self.rewards = _TermModules(dict(items))
        self.stateful = any(reward.stateful for reward in self.rewards.values())
        self.can_fail = any(reward.can_fail for reward in self.rewards.values())
        self.uses_action = any(reward.uses_action for reward in self.rewards.values())
        self._stateful_names = tuple(name for name, reward in self.rewards.items() if reward.stateful)
        self.term_names = tuple(self.rewards.keys())
        self.weights = _TermWeights(self._check_weights(weights))

    def _check_weights(self, weights: object) -> dict[str, float]:
        """Validate ``weights``: ``None`` or a mapping of term names to finite real numbers."""
        if weights is None:
            return {}
        if not isinstance(weights, Mapping):
            raise TypeError(
                f"weights must be a mapping {{term name: weight}} (e.g. {{'effort': 0.1}}) or None, "
                f"got {type(weights).__name__}"
            )
        unknown = [name for name in weights if name not in self.term_names]
        if unknown:
            raise ValueError(f"weights names unknown terms {unknown}; the terms are {list(self.term_names)}")
        return {name: check_finite_scalar(weight, f"weights[{name!r}]") for name, weight in weights.items()}

    def _weighted(self, values: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Multiply the values of the weighted terms by their weights (in place of the dict; tensor-only)."""
        for name, weight in self.weights._buffers.items():
            value = values[name]
            values[name] = value * cast_like(weight, value)
        return values

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        for name, reward in self.rewards.items():
            problem = reward._size_problem(state_size, action_size, f"{who}: term {name!r} ({type(reward).__name__})")
            if problem is not None:
                return problem
        return None

    def terms(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> dict[str, torch.Tensor]:
        """Return ``{name: value[*B]}`` for every term (stateless compounds only)."""
        if self.stateful:
            raise TypeError("this CompoundReward has stateful terms: use step_terms(state, action, memory)")
        return self._weighted({name: reward(error_state, error_action) for name, reward in self.rewards.items()})

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return self.combine_terms(self.terms(error_state, error_action))

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        if self.stateful:
            raise TypeError("this CompoundReward has stateful terms: use step(state, action, memory)")
        return self.combine_terms(
            self._weighted({name: reward._value(error_state, error_action) for name, reward in self.rewards.items()})
        )

    def reset(self, init_state: torch.Tensor) -> TensorDict:
        check_input(init_state, "init_state")
        memory = empty_memory(init_state)
        for name in self._stateful_names:
            memory.set(name, self.rewards[name].reset(init_state))
        return memory

    def step_terms(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[dict[str, torch.Tensor], TensorDict]:
        """Return ``({name: value[*B]}, memory)`` for one step, advancing stateful terms."""
        check_input(state, "state")
        if action is not None or self.uses_action:
            check_input(action, "action")
            check_same_batch(state, action, "state", "action")
        values: dict[str, torch.Tensor] = {}
        if self._stateful_names:
            self._check_memory(memory, state)
            memory = memory.copy()
        for name, reward in self.rewards.items():
            if reward.stateful:
                values[name], sub_memory = reward.step(state, action, read(memory, name))
                memory.set(name, sub_memory)
            else:
                values[name] = reward(state, action)
        return self._weighted(values), memory

    def _check_memory(self, memory: object, state: torch.Tensor) -> None:
        """Raise unless ``memory`` holds an entry for every stateful term (what :meth:`reset` returns)."""
        expected = "memory must be the TensorDict returned by CompoundReward.reset(init_state)"
        if not isinstance(memory, TensorDictBase):
            raise TypeError(f"{expected}, got {type(memory).__name__}")
        missing = [name for name in self._stateful_names if name not in memory.keys()]
        if missing:
            raise TypeError(f"{expected}, got one without the entries {missing} of the stateful terms")
        if memory.batch_size != state.shape[:-1]:
            raise ValueError(
                f"memory has batch size {tuple(memory.batch_size)} but the state has batch shape "
                f"{tuple(state.shape[:-1])}"
            )

    def _step_terms(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[dict[str, torch.Tensor], TensorDict]:
        """:meth:`step_terms` without input validation."""
        values: dict[str, torch.Tensor] = {}
        if not self._stateful_names:
            for name, reward in self.rewards.items():
                values[name] = reward._value(state, action)
            return self._weighted(values), memory
        entries = copy_entries(memory)
        for name, reward in self.rewards.items():
            if reward.stateful:
                values[name], entries[name] = reward._step(state, action, read(memory, name))
            else:
                values[name] = reward._value(state, action)
        return self._weighted(values), TensorDict._new_unsafe(entries, batch_size=memory.batch_size)

    def _step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        values, memory = self._step_terms(state, action, memory)
        return self.combine_terms(values), memory

    def step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        values, memory = self.step_terms(state, action, memory)
        return self.combine_terms(values), memory

    def has_failed(self, state: torch.Tensor) -> torch.Tensor:
        failed = super().has_failed(state)
        for reward in self.rewards.values():
            if reward.can_fail:
                failed = failed | reward.has_failed(state)
        return failed
