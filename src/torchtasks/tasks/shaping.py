"""Potential-based reward shaping that stays correct at termination, truncation and partial resets."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase

from torchtasks._checks import check_finite_scalar
from torchtasks._memory import read
from torchtasks.rewards.base import RewardFunction
from torchtasks.tasks.memory import make_memory
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.wrapper import TaskWrapper

__all__ = ["PotentialShapingTask"]

Potential = Callable[[torch.Tensor], torch.Tensor]

#: the name of the shaping term in the reward breakdown
SHAPING_TERM = "shaping"
#: the name the wrapped task's step reward gets in the breakdown when it has no named terms of its own
TASK_TERM = "task"


class PotentialShapingTask(TaskWrapper):
    """Add potential-based shaping ``F = γ·Φ(s')·(1 − terminated) − Φ(s)`` to a task's step reward.

    Ng, Harada and Russell (1999) showed that adding ``F`` keeps the optimal policies of the task. With
    batched environments that end episodes at different steps, three details decide whether that
    holds, and this wrapper gets them right per environment:

    - after a **termination** (the task's success or failure, or the env's own ``terminated``), the
      next state is absorbing and its potential counts as 0: ``F = −Φ(s)``;
    - after a **truncation** (a time limit) it does not: the value bootstraps from ``s'``, so
      ``F = γ·Φ(s') − Φ(s)``;
    - right after a **partial reset**, ``Φ(s)`` is the potential of the new episode's first state,
      never the old episode's last one (the memory holds ``Φ`` of the state the last step reward saw,
      and a reset writes ``Φ(s_0)``).

    Over an episode of ``T`` steps the shaping terms telescope: ``Σ_t γ^t·F_t = γ^T·Φ(s_T)·[truncated]
    − Φ(s_0)``. ``F`` is evaluated on the state the step reward sees (``next_state`` by default; with
    ``reward_on="state"``, Pyrado's order, every step reward and so ``F`` lags one step), and appears
    in the breakdown as the term ``"shaping"`` (the wrapped task's step reward is the term ``"task"``
    unless it has named terms of its own), so ``RewardSum`` reports it. :meth:`transition` hands the
    env's ``terminated`` down to the shaping task wherever it sits in a tree (inside wrappers, masks and
    composites, where it is the termination of the transition the current sub-task is judged on); the
    fine-grained calls (``step_reward`` sees one state) know only the task's own success and failure.
    With ``reward_on="state"`` the step reward sees ``s_t``, whose step has not ended, so ``terminated``
    (a fact of ``s_{t+1}``) is not applied there.

    Memory: ``"potential"`` (``Φ`` of the last state the step reward saw; ``Φ(s_0)`` at reset) and the
    wrapped task's memory.

    Args:
        task: the task to shape.
        potential: ``Φ``: a callable or module mapping states ``[*B, n]`` to ``[*B]``; any stateless
            torchtasks reward function works (it is called with the state as its error input).
        gamma: the discount of the learner, in ``[0, 1]``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import GoallessTask, PotentialShapingTask
        >>> task = PotentialShapingTask(GoallessTask(EnvSpec(1, 1), ConstantReward(0.0)),
        ...                             potential=lambda s: -s[..., 0].abs(), gamma=0.9)
        >>> state, next_state = torch.tensor([[2.0], [2.0]]), torch.tensor([[1.0], [1.0]])
        >>> out = task.transition(state, torch.zeros(2, 1), next_state, task.reset(state),
        ...                       terminated=torch.tensor([False, True]))
        >>> out.reward  # 0.9·(−1) − (−2) = 1.1 ; terminated: 0 − (−2) = 2
        tensor([1.1000, 2.0000])
    """

    def __init__(self, task: Task, potential: Potential | RewardFunction, gamma: float) -> None:
        super().__init__(task)
        if isinstance(potential, RewardFunction) and potential.stateful:
            raise TypeError(f"potential must be stateless, got the stateful reward {type(potential).__name__}")
        if not callable(potential):
            raise TypeError(f"potential must be a callable or module mapping [*B, n] to [*B], got {potential!r}")
        gamma = check_finite_scalar(gamma, "gamma")
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must lie in [0, 1], got {gamma}")
        self.potential = potential
        self.gamma = gamma
        if SHAPING_TERM in task.term_names:
            raise ValueError(f"the wrapped task already has a term named {SHAPING_TERM!r}")

    @property
    def term_names(self) -> tuple[str, ...]:
        return (*(self.wrapped_task.term_names or (TASK_TERM,)), SHAPING_TERM)

    def _phi(self, state: torch.Tensor) -> torch.Tensor:
        potential = self.potential
        value = potential._value(state, None) if isinstance(potential, RewardFunction) else potential(state)
        if not isinstance(value, torch.Tensor) or value.shape != state.shape[:-1] or not value.is_floating_point():
            got = f"{value.dtype} {tuple(value.shape)}" if isinstance(value, torch.Tensor) else type(value).__name__
            raise ValueError(f"potential must return a floating tensor of shape {tuple(state.shape[:-1])}, got {got}")
        return value.to(state.dtype)

    def _own_memory(self, init_state: torch.Tensor) -> dict[str, torch.Tensor]:
        return {"potential": self._phi(init_state)}

    def _shaping(
        self, source: torch.Tensor, ended: torch.Tensor, memory: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(F, Φ(source))``: the shaping term of a step whose step reward sees ``source``."""
        phi = self._phi(source)
        absorbing = torch.zeros((), dtype=phi.dtype, device=phi.device)
        shaping = self.gamma * torch.where(ended, absorbing, phi) - read(memory, "potential").to(phi.dtype)
        return shaping, phi

    def _with_terms(self, terms: dict[str, torch.Tensor], step: torch.Tensor, shaping: torch.Tensor) -> dict:
        named = dict(terms) if self.wrapped_task.term_names else {TASK_TERM: step}
        named[SHAPING_TERM] = shaping
        return named

    def _shaped_step(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        """The wrapped step reward, then ``F`` on the state it saw: absorbing where the wrapped task ends
        there (its success or failure) or where the env's own ``terminated`` holds for this transition."""
        task = self.wrapped_task
        terms, reward, inner = task._step_terms(state, action, read(memory, "wrapped"), remaining_steps, terminated)
        ended = task._has_succeeded(state, inner) | task._has_failed(state, inner)
        if terminated is not None:
            ended = ended | terminated
        shaping, phi = self._shaping(state, ended, memory)
        memory = make_memory({"potential": phi, "wrapped": inner}, memory.batch_size)
        return self._with_terms(terms, reward, shaping), reward + shaping, memory

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        _, reward, memory = self._shaped_step(state, action, memory, remaining_steps, terminated)
        return reward, memory

    def _step_terms(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        return self._shaped_step(state, action, memory, remaining_steps, terminated)

    def _unfinished_final_reward(
        self, state: torch.Tensor, memory: TensorDictBase, remaining_steps: torch.Tensor, done: torch.Tensor
    ) -> tuple[torch.Tensor, TensorDictBase]:
        # shaping pays no final reward of its own: at the episode end a composite judges the shaped task
        reward, inner = self.wrapped_task._unfinished_final_reward(
            state, read(memory, "wrapped"), remaining_steps, done
        )
        return reward, self._with_inner(memory, inner)
