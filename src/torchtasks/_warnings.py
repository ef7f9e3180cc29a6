"""TorchRL notices that are not a torchtasks user's business, silenced once when torchtasks is imported.

:data:`QUIET_NOTICES` is the one list; :func:`quiet_torchrl_notices` installs it (``import torchtasks`` calls it,
and so do the tests that record warnings, after their own ``simplefilter``). Each filter matches one message
of TorchRL's, by its start, category and (where the warning is attributed to a TorchRL module) module, so a
warning about the user's own code is never matched. Why each is silenced, and how to see them again:
docs/torchrl_integration.md, "Warnings torchtasks silences". This module imports nothing but ``warnings``:
``import torchtasks`` stays free of torch and TorchRL.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple


class Notice(NamedTuple):
    """One silenced warning: regexes matched at the start of the message (case-insensitive) and of the module."""

    message: str
    category: type[Warning]
    module: str  # "" matches any module


QUIET_NOTICES: tuple[Notice, ...] = (
    # torchrl 0.14's Collector (and the collectors built on it) warns for every nn.Module policy whose env has
    # no ``is_init`` entry, i.e. for every feed-forward policy, although only a recurrent policy reads it. Only
    # the message naming InitTracker ALONE: "(InitTracker, TensorDictPrimer)" (a recurrent policy's primers
    # are missing) still shows. The warning is attributed (stacklevel) to torchrl's collector metaclass, so a
    # Collector subclass of the user's own, or a user's warning with the same words, still shows too.
    Notice(
        message=r"The env passed to \w+ is missing transforms required by the policy \(InitTracker\)\. ",
        category=FutureWarning,
        module=r"torchrl\.",
    ),
    # Raised while torchrl.collectors is imported, about torchrl's own WeightUpdaterBase subclasses
    # (four there, two more when its distributed collectors are imported);
    # attributed to the ``abc`` module (class creation), so only the class names tell it from a user's subclass.
    # Without this filter ``python -W error`` cannot import torchtasks.transforms.
    Notice(
        message=(
            r"Creating (VanillaWeightUpdater|MultiProcessedWeightUpdater|RemoteModuleWeightUpdater|RayWeightUpdater"
            r"|DistributedWeightUpdater|RPCWeightUpdater)"
            r" which inherits from WeightUpdaterBase is deprecated\. "
        ),
        category=DeprecationWarning,
        module="",
    ),
)


def quiet_torchrl_notices() -> None:
    """Put a filter ignoring each of :data:`QUIET_NOTICES` in front of the current warning filters.

    Idempotent (``warnings.filterwarnings`` replaces an identical filter instead of adding a second one).
    ``import torchtasks`` runs it once; run it again after a ``warnings.simplefilter(...)`` or inside a
    ``warnings.catch_warnings()`` block that should keep torchtasks' behaviour, since filters added later
    take precedence.

    Example:
        >>> import warnings
        >>> from torchtasks._warnings import quiet_torchrl_notices
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     quiet_torchrl_notices()
        ...     warnings.warn_explicit(
        ...         "The env passed to Collector is missing transforms required by the policy (InitTracker). "
        ...         "From torchrl v0.15 ...", FutureWarning, "_single.py", 1, module="torchrl.collectors._single")
        ...     warnings.warn("a warning about my own code", UserWarning)
        >>> [str(warning.message) for warning in caught]
        ['a warning about my own code']
    """
    for notice in QUIET_NOTICES:
        warnings.filterwarnings("ignore", message=notice.message, category=notice.category, module=notice.module)
