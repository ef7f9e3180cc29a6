"""The Pyrado baseline: one numpy task object per environment, stepped in a Python loop.

A compact re-statement of Pyrado's call chain (``FinalRewTask.step_rew -> DesStateTask.step_rew ->
QuadrErrRewFcn.__call__``, ``is_done``, ``final_rew``) for the benchmarked tasks, following
``reference/pyrado-semantics.md``. It exists only to measure what a per-environment loop costs.
"""

from __future__ import annotations

import numpy as np

from torchtasks.bench.cases import BenchConfig

__all__ = ["PyradoLoop"]


class _QuadraticError:
    def __init__(self, q: np.ndarray, r: np.ndarray) -> None:
        self.Q, self.R = np.diag(q), np.diag(r)

    def __call__(self, err_s: np.ndarray, err_a: np.ndarray) -> float:
        return -float(err_s.dot(self.Q.dot(err_s)) + err_a.dot(self.R.dot(err_a)))


class _DesiredState:
    def __init__(self, config: BenchConfig, goal: float) -> None:
        self.state_des = np.full(config.state_size, goal)
        self.rew_fcn = _QuadraticError(config.q().numpy(), config.r().numpy())
        self.low, self.high, self.threshold = -config.bound, config.bound, config.threshold

    def reset(self) -> None:
        pass

    def step_rew(self, state: np.ndarray, act: np.ndarray, rem: int) -> float:
        return self.rew_fcn(self.state_des - state, -act)

    def has_succeeded(self, state: np.ndarray) -> bool:
        return bool(np.linalg.norm(self.state_des - state) < self.threshold)

    def has_failed(self, state: np.ndarray) -> bool:
        return not bool(np.all((self.low <= state) & (state <= self.high)))

    def is_done(self, state: np.ndarray) -> bool:
        return self.has_succeeded(state) or self.has_failed(state)

    def compute_final_rew(self, state: np.ndarray, rem: int) -> float:
        return 0.0

    def final_rew(self, state: np.ndarray, rem: int) -> float:
        return self.compute_final_rew(state, rem)


class _FinalReward(_DesiredState):
    def __init__(self, config: BenchConfig, goal: float) -> None:
        super().__init__(config, goal)
        self.factor = config.factor
        self.yielded = False

    def reset(self) -> None:
        self.yielded = False

    def compute_final_rew(self, state: np.ndarray, rem: int) -> float:
        if self.yielded:
            return 0.0
        self.yielded = True
        if self.has_failed(state):
            return -self.factor
        if self.has_succeeded(state):
            return self.factor
        return 0.0


class _Parallel:
    def __init__(self, tasks: list[_FinalReward]) -> None:
        self.tasks = tasks
        self.succ = [False] * len(tasks)
        self.fail = [False] * len(tasks)

    def step_rew(self, state: np.ndarray, act: np.ndarray, rem: int) -> float:
        rew = sum(t.step_rew(state, act, rem) for i, t in enumerate(self.tasks) if not (self.succ[i] or self.fail[i]))
        for i, task in enumerate(self.tasks):
            if not (self.succ[i] or self.fail[i]) and task.is_done(state):
                if task.has_succeeded(state):
                    self.succ[i] = True
                else:
                    self.fail[i] = True
                rew += task.final_rew(state, rem)
        return rew

    def is_done(self, state: np.ndarray) -> bool:
        return all(self.succ) or any(self.fail)

    def final_rew(self, state: np.ndarray, rem: int) -> float:
        return sum(task.compute_final_rew(state, rem) for task in self.tasks)


class _Sequential(_Parallel):
    def __init__(self, tasks: list[_FinalReward]) -> None:
        super().__init__(tasks)
        self.idx = 0

    def step_rew(self, state: np.ndarray, act: np.ndarray, rem: int) -> float:
        i = self.idx
        rew = 0.0
        if not (self.succ[i] or self.fail[i]):
            task = self.tasks[i]
            rew += task.step_rew(state, act, rem)
            if task.is_done(state):
                if task.has_succeeded(state):
                    self.succ[i] = True
                else:
                    self.fail[i] = True
                rew += task.final_rew(state, rem)
                self.idx = (i + 1) % len(self.tasks)
        return rew

    def is_done(self, state: np.ndarray) -> bool:
        return all(self.succ) or self.tasks[0].has_failed(state)


class PyradoLoop:
    """``batch`` Pyrado-style task objects of case ``name`` (``"T1"``, ``"T2"``, ``"T3"``) stepped one by one.

    Example:
        >>> import numpy as np
        >>> loop = PyradoLoop("T1", BenchConfig(), batch=2)
        >>> loop.step(np.zeros((2, 17)), np.zeros((2, 6)), np.zeros(2, dtype=bool))[0]
        array([100., 100.])
    """

    def __init__(self, name: str, config: BenchConfig, batch: int) -> None:
        def make() -> object:
            if name == "T1":
                return _FinalReward(config, config.goals[0])
            tasks = [_FinalReward(config, goal) for goal in config.goals]
            return _Parallel(tasks) if name == "T2" else _Sequential(tasks)

        self.tasks = [make() for _ in range(batch)]

    def step(self, state: np.ndarray, action: np.ndarray, truncated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Step every environment: reward on ``state``, done and final reward on ``state``."""
        rewards = np.empty(len(self.tasks))
        dones = np.empty(len(self.tasks), dtype=bool)
        for i, task in enumerate(self.tasks):
            reward = task.step_rew(state[i], action[i], 0)
            done = task.is_done(state[i]) or bool(truncated[i])
            if done:
                reward += task.final_rew(state[i], 0)
            rewards[i] = reward
            dones[i] = done
        return rewards, dones
