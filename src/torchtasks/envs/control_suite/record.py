"""One Control Suite task as data: its model, step, observation, task state, reward and resets.

A :class:`ControlSuiteTask` says everything :func:`~torchtasks.envs.control_suite.control_suite_env` needs, as
dm_control's ``suite/<domain>.py`` says it in code: the model (:mod:`~torchtasks.envs.control_suite.models`), the
control step, the observation (dm_control's entries, in its order, as readings), the task-state entries the reward
reads (readings too), the reward as reward terms on them, and the reset steps. The per-domain modules
(``acrobot``, ``ball_in_cup``, ...) hold one table ``TASKS`` of these records each. The helpers here turn the
recurring pieces of dm_control's rewards into terms: :func:`tolerance` (``rewards.tolerance`` on named state
entries), :func:`small_control` (``(4 + tolerance(ctrl, margin=1, value_at_margin=0, sigmoid="quadratic")) / 5``)
and :func:`xmat` (entries of bodies' rotation matrices by component name, ``xmat['torso', 'zz']``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.readings import Reading
from torchtasks.rewards import AffineReward, RewardFunction, ToleranceReward

__all__ = ["ControlSuiteTask", "StateColumns", "small_control", "tolerance", "xmat"]

#: where each task-state entry sits in the task's state vector: ``{entry: [columns]}``
StateColumns = Mapping[str, Sequence[int]]
#: readings by entry name, in order
Entries = dict[str, list[Reading]]

#: the nine components of a rotation matrix, row-major, as dm_control names them (``xmat['pole', 'zz']``)
_COMPONENTS = ("xx", "xy", "xz", "yx", "yy", "yz", "zx", "zy", "zz")
#: dm_control's episodes last 1000 control steps in every task here
EPISODE_STEPS = 1000


@dataclass(frozen=True)
class ControlSuiteTask:
    """One Control Suite task: ``domain``, ``task`` and how to build its env and reward.

    Attributes:
        domain, task: dm_control's names (``"walker"``, ``"walk"``).
        time_limit: the episode in seconds (1000 control steps in every task here).
        control_timestep: the control step in seconds, or ``None``: one physics step (dm_control's default).
        observation: ``model -> {entry: readings}``, dm_control's ``get_observation`` entries in its order.
        state: ``model -> {entry: readings}``, the task-state entries the reward reads.
        reward: ``(model, columns) -> RewardFunction`` on the task state (``columns`` locates each entry).
        resets: ``model -> Resets``, dm_control's ``initialize_episode`` as reset steps.
        notes: what differs from dm_control, if anything, for the docs.
    """

    domain: str
    task: str
    time_limit: float
    control_timestep: float | None
    observation: Callable[[mujoco.MjModel], Entries]
    state: Callable[[mujoco.MjModel], Entries]
    reward: Callable[[mujoco.MjModel, StateColumns], RewardFunction]
    resets: Callable[[mujoco.MjModel], Resets]
    notes: str = ""

    @property
    def name(self) -> str:
        """``"<domain>-<task>"``."""
        return f"{self.domain}-{self.task}"


def xmat(model: mujoco.MjModel, *pairs: tuple[str, str]) -> Reading:
    """Entries of bodies' world rotation matrices, ``(body, component)`` each in order (``("torso", "zz")``): one
    reading of the ``xmat`` rows they span.

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body name="pole"><joint/><geom size="0.1"/>'
        ...                                        '</body></worldbody></mujoco>')
        >>> xmat(model, ("pole", "zz"), ("pole", "xz")).index
        (8, 2)
    """
    rows = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body) for body, _ in pairs]
    for (body, component), row in zip(pairs, rows, strict=True):
        if row < 0 or component not in _COMPONENTS:
            raise ValueError(f"xmat: no body {body!r} or component {component!r} (one of {_COMPONENTS})")
    start = min(rows)
    index = tuple(9 * (row - start) + _COMPONENTS.index(c) for row, (_, c) in zip(rows, pairs, strict=True))
    return readings.data_field("xmat", start, max(rows) + 1, index=index)


def tolerance(
    columns: StateColumns,
    entry: str,
    bounds: tuple[float, float] = (0.0, 0.0),
    margin: float = 0.0,
    sigmoid: str = "gaussian",
    value_at_margin: float = 0.1,
    combine: str = "product",
) -> ToleranceReward:
    """dm_control's ``rewards.tolerance`` of the task-state entry ``entry`` (its entries combined by product or
    mean), with dm_control's defaults.

    Example:
        >>> import torch
        >>> tolerance({"height": [0]}, "height", bounds=(1.2, math.inf), margin=0.6)(torch.tensor([[1.5]]), None)
        tensor([1.])
    """
    return ToleranceReward(
        bounds=bounds,
        margin=margin,
        sigmoid=sigmoid,
        value_at_margin=value_at_margin,
        indices=list(columns[entry]),
        combine=combine,
    )


def small_control(columns: StateColumns, entry: str = "control") -> AffineReward:
    """dm_control's small-control factor: ``(4 + mean(tolerance(ctrl, margin=1, value_at_margin=0,
    sigmoid="quadratic"))) / 5`` on the task-state entry of the controls.

    Example:
        >>> import torch
        >>> small_control({"control": [0, 1]})(torch.tensor([[0.0, 1.0]]), None)
        tensor([0.9000])
    """
    return AffineReward(
        tolerance(columns, entry, margin=1.0, sigmoid="quadratic", value_at_margin=0.0, combine="mean"),
        scale=0.2,
        offset=0.8,
    )


def upright(columns: StateColumns, entry: str) -> ToleranceReward:
    """``(1 + zz) / 2`` for ``zz`` in ``[-1, 1]``, as dm_control writes it for quadruped:
    ``tolerance(zz, bounds=(1, inf), sigmoid="linear", margin=2, value_at_margin=0)``.

    Example:
        >>> import torch
        >>> upright({"zz": [0]}, "zz")(torch.tensor([[0.0]]), None)
        tensor([0.5000])
    """
    return tolerance(columns, entry, bounds=(1.0, math.inf), margin=2.0, sigmoid="linear", value_at_margin=0.0)
