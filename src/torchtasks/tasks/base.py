"""The earlier home of the task protocol and its wrappers: re-exports them.

:class:`Task` lives in :mod:`torchtasks.tasks.protocol`, :class:`TaskWrapper`, :class:`ForwardingTask` and
:func:`all_tasks` in :mod:`torchtasks.tasks.wrapper`, :class:`TaskOutput` in :mod:`torchtasks.tasks.output`.
"""

from torchtasks.tasks.output import TaskOutput
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.wrapper import ForwardingTask, TaskWrapper, all_tasks

__all__ = ["ForwardingTask", "Task", "TaskOutput", "TaskWrapper", "all_tasks"]
