"""torchtasks: batched, differentiable tasks and rewards for TorchRL.

Layers (imports only point down): :mod:`torchtasks.spaces`, :mod:`torchtasks.rewards`,
:mod:`torchtasks.tasks`, :mod:`torchtasks.predefined`, :mod:`torchtasks.transforms` (the TorchRL face of a
task: the task transform, goal commands, curricula, levels, seeding and checkpoints), :mod:`torchtasks.stats`
(reads collected data), :mod:`torchtasks.envs`.

Importing the package silences two TorchRL notices that are not about the user's code (``_warnings.py``;
docs/torchrl_integration.md, "Warnings torchtasks silences").
"""

from torchtasks._warnings import quiet_torchrl_notices

quiet_torchrl_notices()

__version__ = "0.1.0"
