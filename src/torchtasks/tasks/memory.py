"""Small, fast helpers to build and combine task memory (TensorDicts of per-environment state)."""

from __future__ import annotations

from typing import NamedTuple

import torch
from tensordict import TensorDict, TensorDictBase

from torchtasks._memory import make_memory, read

__all__ = ["MemoryLayout", "check_memory_layout", "make_memory", "memory_layout", "where_memory"]


class MemoryLayout(NamedTuple):
    """The keys of a task's memory: all keys of one level, and the layouts of its nested sub-memories."""

    keys: frozenset[str]
    nested: dict[str, MemoryLayout]

    def describe(self) -> str:
        """The layout as nested braces, e.g. ``{paid, wrapped: {state_des}}``."""
        parts = [f"{key}: {self.nested[key].describe()}" if key in self.nested else key for key in sorted(self.keys)]
        return "{" + ", ".join(parts) + "}"


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
        other = read(old, key)
        if isinstance(value, TensorDictBase):
            entries[key] = where_memory(condition, value, other)
        else:
            entries[key] = torch.where(_expand_condition(condition, value), value, other)
    return make_memory(entries, new.batch_size)


def memory_layout(memory: TensorDictBase) -> MemoryLayout:
    """Return the :class:`MemoryLayout` of ``memory``."""
    nested = {key: memory_layout(value) for key, value in memory.items() if isinstance(value, TensorDictBase)}
    return MemoryLayout(frozenset(memory.keys()), nested)


def _top_keys(memory: TensorDictBase) -> object:
    # a plain TensorDict keeps its entries in a dict: comparing its keys view with a frozenset is one C call
    if type(memory) is TensorDict:
        return memory._tensordict.keys()
    return set(memory.keys())


def _mismatch(memory: TensorDictBase, layout: MemoryLayout, path: tuple[str, ...]) -> str | None:
    got = set(memory.keys())
    where = "memory" if not path else f"memory[{path!r}]"
    if got != layout.keys:
        missing, extra = sorted(layout.keys - got), sorted(got - layout.keys)
        details = []
        if missing:
            details.append(f"missing key(s) {missing}")
        if extra:
            details.append(f"unexpected key(s) {extra}")
        return f"{where} has {' and '.join(details)}"
    for key, sub in layout.nested.items():
        value = read(memory, key)
        if not isinstance(value, TensorDictBase):
            return f"{where}[{key!r}] must be a TensorDict (the memory of a sub-task), got {type(value).__name__}"
        found = _mismatch(value, sub, (*path, key))
        if found is not None:
            return found
    return None


def _matches(memory: TensorDictBase, layout: MemoryLayout) -> bool:
    if _top_keys(memory) != layout.keys:
        return False
    for key, sub in layout.nested.items():
        value = read(memory, key)
        if not isinstance(value, TensorDictBase) or not _matches(value, sub):
            return False
    return True


def check_memory_layout(memory: TensorDictBase, layout: MemoryLayout, owner: str) -> None:
    """Raise a ``ValueError`` naming the missing or unexpected keys unless ``memory`` has ``layout``.

    The check compares key sets level by level (one set comparison per nested sub-memory), so it
    is cheap enough for every call; the detailed message is built only on a mismatch.
    """
    if _matches(memory, layout):
        return
    problem = _mismatch(memory, layout, ())
    raise ValueError(
        f"the memory does not belong to this {owner}: {problem}; this task expects the layout "
        f"{layout.describe()}. Pass the memory returned by this task's reset() or by its previous call."
    )
