"""Per-env action delay of the batched MuJoCo engine: the policy's last actions and the one each env applies.

Pyrado's ``ActDelayWrapper`` for a batch. With ``BatchedMujocoEnv(..., max_action_delay=d)``, env ``i`` applies the
policy's action of ``delay[i]`` steps earlier, and after each of its resets its queue holds zeros, so the first
``delay[i]`` steps of an episode apply zero actions (the declared action map then acts on the applied action).
``delay`` is the domain field ``"action_delay"`` (:func:`action_delay_field`: integer in ``[0, d]``, nominal 0), drawn
like a mass by a ``DomainParam`` with ``roundint=True``; a value set takes effect at the env's next reset only.
``("next", "applied_action")`` (float64 ``[num_envs, nu]``, zeros at reset) is the action the physics ran, in the
policy's action space; ``"action"``, which a task judges, and the ``last_action`` readings stay the policy's. A
non-finite policy action breaks the step it is given in, as without a delay: it is never queued, so every applied
action is finite. With ``d = 0`` there is no field, no entry and no work.

:class:`ActionQueue` keeps, per env, the active delay, the last ``d`` policy actions and the action applied in the
last step, and gathers the applied actions of all envs with array operations; the env owns one.

Example:
    >>> import torch
    >>> from torchtasks.envs import BatchedMujocoEnv, readings
    >>> xml = '''<mujoco><worldbody><body><joint name="hinge"/><geom size="0.1"/></body></worldbody>
    ...   <actuator><motor joint="hinge"/></actuator></mujoco>'''
    >>> env = BatchedMujocoEnv(xml, 2, observation=readings.joint_pos("hinge"), max_action_delay=1, seed=0)
    >>> env.set_domain({"action_delay": torch.tensor([0.0, 1.0], dtype=torch.float64)})  # env 1: one step late
    >>> td = env.reset()
    >>> [env.step(td.set("action", torch.full((2, 1), a)))["next", "applied_action"][:, 0].tolist() for a in (0.5, 1.0)]
    [[0.5, 0.0], [1.0, 0.5]]
    >>> env.close()
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from torchtasks.domain.fields import DomainField

__all__ = ["ACTION_DELAY", "APPLIED_ACTION_KEY", "ActionQueue", "action_delay_field"]

#: the domain field of the delay (steps)
ACTION_DELAY = "action_delay"
#: the entry of the action the physics ran in a step (float64 ``[num_envs, nu]``, in the policy's action space)
APPLIED_ACTION_KEY = "applied_action"
#: what a checkpoint keeps of a queue (the delay each env runs now, its last actions, the action it applied last)
SAVED_KEYS = ("action_delay", "action_history", "applied_action")


def action_delay_field(max_delay: int) -> DomainField:
    """The domain field ``"action_delay"``: an integer number of steps in ``[0, max_delay]``, nominal 0.

    Example:
        >>> field = action_delay_field(3)
        >>> field.name, field.rule, field.nominal.item(), field.integer
        ('action_delay', 'integer in [0, 3]', 0.0, True)
    """
    return DomainField(
        ACTION_DELAY,
        torch.Size([]),
        torch.tensor(0.0, dtype=torch.float64),
        0.0,
        float(max_delay),
        False,
        (),
        False,
        "action delay in steps (at most max_action_delay), taken at the env's next reset",
        integer=True,
    )


class ActionQueue:
    """The last ``max_delay`` policy actions of each env and the delayed action each env applies.

    :meth:`push` takes the policy's actions of a step and returns, per env, the one of ``delay[i]`` steps earlier
    (zeros while the env's episode has had fewer steps); :meth:`reset` empties the queues of the reset envs and
    gives them their delays for the new episode. No Python loop over envs.

    Args:
        num_envs: number of envs.
        action_size: size of one action.
        max_delay: the largest delay (>= 1).

    Example:
        >>> import numpy as np
        >>> queue = ActionQueue(2, 1, max_delay=2)
        >>> queue.reset(slice(None), np.array([0, 2]))  # env 0 undelayed, env 1 two steps late
        >>> [queue.push(np.array([[t], [t]]), None)[:, 0].tolist() for t in (1.0, 2.0, 3.0)]
        [[1.0, 0.0], [2.0, 0.0], [3.0, 1.0]]
    """

    def __init__(self, num_envs: int, action_size: int, max_delay: int) -> None:
        self.max_delay = max_delay
        # column k: the policy's action k steps before the last one pushed (column 0: the last one); the last column
        # is the one a push drops, so the history of the last max_delay actions is columns 0 .. max_delay - 1
        self._queue = np.zeros((num_envs, max_delay + 1, action_size))
        #: each env's delay in this episode (steps)
        self.delay = np.zeros(num_envs, dtype=np.int64)
        self._rows = np.arange(num_envs)
        #: the action each env applied in its last step (zeros after its reset), float64 ``[num_envs, action_size]``
        self.applied = np.zeros((num_envs, action_size))

    @property
    def history(self) -> np.ndarray:
        """The last ``max_delay`` policy actions of each env, newest first: ``[num_envs, max_delay, action_size]``."""
        return self._queue[:, : self.max_delay]

    def push(self, action: np.ndarray, stepped: np.ndarray | None) -> np.ndarray:
        """Queue the policy's ``action`` (``[num_envs, action_size]``) of the envs ``stepped`` (None: all) and return
        :attr:`applied`, whose rows of those envs are now their delayed actions (the others' are kept)."""
        queue = self._queue
        if stepped is None:
            queue[:, 1:] = queue[:, :-1]  # numpy copies overlapping operands as if they did not overlap
            queue[:, 0] = action
            # the gather queue[i, delay[i]] for every i; an indexing gather: np.take_along_axis took 23 us for 64 envs
            # of 12 actions (it builds index grids), this 2.7 us (the whole push 7.6 us)
            np.copyto(self.applied, queue[self._rows, self.delay])
        else:  # an env skipped by a broken step keeps its queue, as it keeps its state and controls
            rows = queue[stepped]
            rows[:, 1:] = rows[:, :-1]
            rows[:, 0] = action[stepped]
            queue[stepped] = rows
            self.applied[stepped] = rows[np.arange(stepped.size), self.delay[stepped]]
        return self.applied

    def reset(self, rows: slice | np.ndarray, delays: np.ndarray | int) -> None:
        """Empty the queues of the envs ``rows`` and give them ``delays`` (whole numbers, checked by the caller)."""
        self._queue[rows] = 0.0
        self.applied[rows] = 0.0
        self.delay[rows] = delays

    # ------------------------------------------------------------------ checkpoints
    def saved(self) -> dict[str, torch.Tensor]:
        """The delays, the histories and the applied actions, as tensors (copies): :data:`SAVED_KEYS`."""
        return {
            "action_delay": torch.from_numpy(self.delay.copy()),
            "action_history": torch.from_numpy(self.history.copy()),
            "applied_action": torch.from_numpy(self.applied.copy()),
        }

    def check_saved(self, saved: Mapping[str, Any], owner: str) -> None:
        """Refuse a saved delay outside ``[0, max_delay]`` (shapes and dtypes are checked with the other entries)."""
        delay = saved["action_delay"].cpu().numpy()
        if ((delay < 0) | (delay > self.max_delay)).any():
            raise ValueError(
                f"{owner}: the saved 'action_delay' must hold delays in [0, {self.max_delay}] (max_action_delay), "
                f"got {delay.tolist()}"
            )

    def load(self, saved: Mapping[str, torch.Tensor]) -> None:
        """Put what :meth:`saved` wrote (checked) back."""
        self.delay[:] = saved["action_delay"].cpu().numpy()
        self.history[:] = saved["action_history"].cpu().numpy()
        self._queue[:, self.max_delay] = 0.0
        self.applied[:] = saved["applied_action"].cpu().numpy()
