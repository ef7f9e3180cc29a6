"""torchtasks: batched, differentiable tasks and rewards for TorchRL.

Layers (imports only point down): :mod:`torchtasks.spaces`, :mod:`torchtasks.rewards`,
:mod:`torchtasks.tasks`, :mod:`torchtasks.predefined`, :mod:`torchtasks.transforms` (the TorchRL face of a
task), :mod:`torchtasks.commands` (goal commands, which look for the TaskTransforms beside them),
:mod:`torchtasks.stats` (reads collected data), :mod:`torchtasks.envs`.
"""

__version__ = "0.1.0"
