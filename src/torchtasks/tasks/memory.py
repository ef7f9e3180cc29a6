"""Small, fast helpers to build and combine task memory (TensorDicts of per-environment state)."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from tensordict import TensorDict, TensorDictBase

__all__ = ["make_memory", "where_memory"]


def make_memory(entries: Mapping[str, torch.Tensor | TensorDictBase], batch_size: torch.Size) -> TensorDict:
    """Return a TensorDict of ``entries`` with ``batch_size`` (entries are trusted to have it).

    Task code builds memory many times per step; this skips TensorDict's per-entry validation,
    which the tasks guarantee by construction.
    """
    return TensorDict._new_unsafe(dict(entries), batch_size=batch_size)


def _expand_condition(condition: torch.Tensor, value: torch.Tensor) -> torch.Tensor:
    extra = value.ndim - condition.ndim
    return condition.reshape(condition.shape + (1,) * extra) if extra else condition


def where_memory(condition: torch.Tensor, new: TensorDictBase, old: TensorDictBase) -> TensorDictBase:
    """Return memory that is ``new`` where ``condition`` (``bool[*B]``) holds and ``old`` elsewhere.

    This is how tasks keep the memory of environments untouched when they are not concerned by a
    step (an inactive sub-task, an environment that is not being reset).
    """
    if new is old:
        return new
    entries: dict[str, torch.Tensor | TensorDictBase] = {}
    for key, value in new.items():
        other = old.get(key)
        if isinstance(value, TensorDictBase):
            entries[key] = where_memory(condition, value, other)
        else:
            entries[key] = torch.where(_expand_condition(condition, value), value, other)
    return make_memory(entries, new.batch_size)
