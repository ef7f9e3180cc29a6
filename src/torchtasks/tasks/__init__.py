"""Tasks: batched, functional evaluation of transitions with per-environment memory in a TensorDict."""

from torchtasks.tasks.command_tracking import CommandTrackingTask
from torchtasks.tasks.composite import CompositeTask
from torchtasks.tasks.constrained import ConstrainedTask, Constraint
from torchtasks.tasks.desired_state import DesiredStateTask, RadiallySymmetricDesiredStateTask
from torchtasks.tasks.final_reward import BestStateFinalRewardTask, FinalRewardMode, FinalRewardTask
from torchtasks.tasks.flipping import FlippingTask
from torchtasks.tasks.goalless import ConditionTask, DesiredSpaceTask, GoallessTask, OptimizationTask
from torchtasks.tasks.groups import RewardGroupsTask
from torchtasks.tasks.leaf import RewardTask
from torchtasks.tasks.masked import MaskedTask
from torchtasks.tasks.output import TaskOutput
from torchtasks.tasks.parallel import ParallelTasks
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.sequential import SequentialTasks
from torchtasks.tasks.shaping import PotentialShapingTask
from torchtasks.tasks.success import never_succeeded, proximity_succeeded
from torchtasks.tasks.velocity_tracking import (
    VELOCITY_TRACKING_WEIGHTS,
    velocity_tracking_state,
    velocity_tracking_task,
)
from torchtasks.tasks.wrapper import ForwardingTask, TaskWrapper, all_tasks

__all__ = [
    "VELOCITY_TRACKING_WEIGHTS",
    "BestStateFinalRewardTask",
    "CommandTrackingTask",
    "CompositeTask",
    "ConditionTask",
    "ConstrainedTask",
    "Constraint",
    "DesiredSpaceTask",
    "DesiredStateTask",
    "FinalRewardMode",
    "FinalRewardTask",
    "FlippingTask",
    "ForwardingTask",
    "GoallessTask",
    "MaskedTask",
    "OptimizationTask",
    "ParallelTasks",
    "PotentialShapingTask",
    "RadiallySymmetricDesiredStateTask",
    "RewardGroupsTask",
    "RewardTask",
    "SequentialTasks",
    "Task",
    "TaskOutput",
    "TaskWrapper",
    "all_tasks",
    "never_succeeded",
    "proximity_succeeded",
    "velocity_tracking_state",
    "velocity_tracking_task",
]
