"""Fast access to memory TensorDicts: the few operations task and reward steps make many times per call.

``TensorDict.get`` and ``TensorDict.items`` validate and unravel keys (about 2-3 µs a call); a task
step reads a handful of flat keys from memory it built itself. For a plain ``TensorDict`` these
helpers go to its entry dict directly; any other ``TensorDictBase`` (lazy stacks, views) takes the
public methods.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from tensordict import TensorDict, TensorDictBase

__all__ = ["copy_entries", "make_memory", "read"]


def read(memory: TensorDictBase, key: str) -> torch.Tensor | TensorDictBase:
    """Return ``memory[key]`` for a flat string key (``KeyError`` when it is missing)."""
    if type(memory) is TensorDict:
        return memory._tensordict[key]
    value = memory.get(key, None)
    if value is None:
        raise KeyError(key)
    return value


def copy_entries(memory: TensorDictBase) -> dict[str, torch.Tensor | TensorDictBase]:
    """Return a new ``{key: value}`` dict of the top-level entries of ``memory``."""
    if type(memory) is TensorDict:
        return dict(memory._tensordict)
    return dict(memory.items())


def make_memory(values: Mapping[str, torch.Tensor | TensorDictBase], batch_size: torch.Size) -> TensorDict:
    """Return a TensorDict of ``values`` with ``batch_size`` (entries are trusted to have it).

    Task code builds memory many times per step; this skips TensorDict's per-entry validation,
    which the tasks guarantee by construction.
    """
    return TensorDict._new_unsafe(dict(values), batch_size=batch_size)
