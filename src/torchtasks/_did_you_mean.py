"""The one "did you mean" of torchtasks: the closest valid choices to a misspelt name (no torch import).

Read by the argument checks (:mod:`torchtasks._checks` re-exports :func:`did_you_mean`), the resolver of named
targets, the presets' env ids and the ``torchtasks`` command and the examples' parsers (commands, env ids and
options), which must answer a mistake without importing torch.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence

#: how close a choice must be (``difflib``'s ratio) to be suggested for a misspelt name
CUTOFF = 0.8


def closest(name: str, choices: Sequence[str], *, n: int = 1, cutoff: float = CUTOFF) -> list[str]:
    """The at most ``n`` choices closest to ``name``, closest first (``[]`` when none has ``cutoff`` or more).

    Example:
        >>> closest("--quik", ["--quick", "--output", "--seed"])
        ['--quick']
        >>> closest("--all", ["--help"])
        []
    """
    return difflib.get_close_matches(name, list(choices), n=n, cutoff=cutoff)


def did_you_mean(name: str, choices: Sequence[str], *, n: int = 1, cutoff: float = CUTOFF) -> str:
    """``"; did you mean 'x'?"`` for the choices closest to a misspelt ``name`` (``""`` when none is close).

    Dotted names (``reward.rewards.effort.weight``) are compared whole, so one wrong letter in a long
    path still finds its match. ``n`` is the most choices named, closest first (``"'x', 'y' or 'z'"``);
    ``cutoff`` is :func:`closest`'s.

    Example:
        >>> did_you_mean("reward.rewards.efort.weight", ["reward.rewards.effort.weight", "reward.Q"])
        "; did you mean 'reward.rewards.effort.weight'?"
        >>> did_you_mean("speed", ["reward.Q"])
        ''
        >>> did_you_mean("body_mass:thigh", ["body_mass:thigh_left", "body_mass:thigh", "gravity"], n=3)
        "; did you mean 'body_mass:thigh' or 'body_mass:thigh_left'?"
    """
    close = [repr(choice) for choice in closest(name, choices, n=n, cutoff=cutoff)]
    if not close:
        return ""
    listed = close[0] if len(close) == 1 else f"{', '.join(close[:-1])} or {close[-1]}"
    return f"; did you mean {listed}?"
