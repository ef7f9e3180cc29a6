"""Fast access to TensorDicts in the hot path: task memory, and the env data a transform reads and writes.

``TensorDict.get``, ``set`` and ``items`` validate and unravel keys (about 1-3 µs a call); a task
step reads a handful of flat keys from memory it built itself, and the transform writes values it
computed with the right shapes. For a plain ``TensorDict`` these helpers skip that work; any other
``TensorDictBase`` (lazy stacks, views) takes the public methods.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

__all__ = [
    "copy_entries",
    "has_leaves",
    "hollow_paths",
    "make_memory",
    "read",
    "set_records",
    "td_get",
    "td_set",
    "unshared",
    "with_hollow",
    "without_hollow",
]


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


def td_get(tensordict: TensorDictBase, key: str | tuple[str, ...], default: object = None) -> object:
    """Return ``tensordict.get(key, default)`` for an unravelled key, without re-validating the key."""
    if type(tensordict) is TensorDict:
        if isinstance(key, str):
            return tensordict._get_str(key, default)
        return tensordict._get_tuple(key, default)
    return tensordict.get(key, default)


def td_set(tensordict: TensorDictBase, key: str | tuple[str, ...], value: torch.Tensor | TensorDictBase) -> None:
    """``tensordict.set(key, value)`` for an unravelled key and a value already of the right batch shape.

    The value is trusted (computed by the task from this tensordict's entries): TensorDict's per-call
    validation, about 2 µs of a 2.5 µs set, is skipped.
    """
    if type(tensordict) is TensorDict:
        if isinstance(key, str):
            tensordict._set_str(key, value, inplace=False, validated=True)
        else:
            tensordict._set_tuple(key, value, inplace=False, validated=True)
        return
    tensordict.set(key, value)


def set_records(
    tensordict: TensorDictBase, prefix: tuple[str, ...], values: Mapping[tuple[str, ...], torch.Tensor]
) -> None:
    """Write ``values`` (by key parts under ``prefix``, each of ``tensordict``'s batch shape) into ``tensordict``.

    A transform's records of a step (``("domain", name)``) are new keys of
    a fresh step's data: when ``prefix``'s first part is absent, the whole subtree is built and set at once (one set
    instead of one per value, each creating or walking the nodes on its path); otherwise each value is set at its
    key. The values are trusted (the caller's copies, of the right shape).
    """
    if type(tensordict) is not TensorDict or tensordict._tensordict.get(prefix[0]) is not None:
        for parts, value in values.items():
            td_set(tensordict, (*prefix, *parts), value)
        return
    batch, device = tensordict.batch_size, tensordict.device
    tree: dict[str, Any] = {}
    for parts, value in values.items():
        node = tree
        for part in (*prefix[1:], *parts[:-1]):
            node = node.setdefault(part, {})
        node[parts[-1]] = value

    def build(node: dict[str, Any]) -> TensorDict:
        return TensorDict._new_unsafe(
            {key: build(child) if isinstance(child, dict) else child for key, child in node.items()},
            batch_size=batch,
            device=device,
        )

    td_set(tensordict, prefix[0], build(tree))


def _storages(node: TensorDictBase, into: set[int]) -> set[int]:
    """Add the storage addresses of the tensors of ``node`` (nested) to ``into``; return it."""
    for value in node._tensordict.values() if type(node) is TensorDict else node.values():
        if isinstance(value, torch.Tensor):
            into.add(value.untyped_storage().data_ptr())
        elif isinstance(value, TensorDictBase):
            _storages(value, into)
    return into


def _unshared(node: TensorDictBase, taken: set[int]) -> TensorDictBase:
    entries = copy_entries(node)
    changed = False
    for key, value in entries.items():
        if isinstance(value, torch.Tensor):
            if value.numel() and value.untyped_storage().data_ptr() in taken:
                entries[key], changed = value.clone(), True
        elif isinstance(value, TensorDictBase):
            fresh = _unshared(value, taken)
            if fresh is not value:
                entries[key], changed = fresh, True
    if not changed:
        return node
    if type(node) is TensorDict:
        return TensorDict._new_unsafe(entries, batch_size=node.batch_size, device=node.device)
    return TensorDict(entries, batch_size=node.batch_size, device=node.device)


def unshared(output: TensorDictBase, *inputs: torch.Tensor | TensorDictBase) -> TensorDictBase:
    """``output`` with every tensor that shares storage with a tensor of ``inputs`` replaced by a copy.

    A task's step may return a memory tensor it was given (a desired state kept for the episode, the goal, the
    state): written as it is under ``"next"``, the entry would share its storage with the root entry it came from,
    and TorchRL's shared buffers (a ``ParallelEnv`` worker copies the step's output into the root in place) or any
    in-place write would change one frame's data through the other. ``output`` is returned as it is (the same
    object) when nothing is shared; no argument is modified. One storage address per tensor: no data is read.
    """
    taken: set[int] = set()
    for value in inputs:
        if isinstance(value, torch.Tensor):
            taken.add(value.untyped_storage().data_ptr())
        else:
            _storages(value, taken)
    return _unshared(output, taken)


# ------------------------------------------------------------------ memory in env data
# A memory-less sub-task (a GoallessTask with a stateless reward, a condition) has an empty sub-memory. TorchRL's
# batched envs refuse an empty Composite in the specs, and its RemoveEmptySpecs puts empty nodes back with
# TensorDict.create_nested, which replaces their parent (and so the latch beside it): the env data hold the memory
# without its empty sub-memories, and the transform puts them back before the task reads the memory.
def hollow_paths(layout: Any, path: tuple[str, ...] = ()) -> tuple[tuple[tuple[str, ...], Any], ...]:
    """``(path, layout)`` of the outermost sub-memories of a memory ``layout`` (a ``MemoryLayout``) without tensors."""
    found: list[tuple[tuple[str, ...], Any]] = []
    for key in sorted(layout.keys):
        sub = layout.nested.get(key)
        if sub is None:
            continue
        if has_leaves(sub):
            found.extend(hollow_paths(sub, (*path, key)))
        else:
            found.append(((*path, key), sub))
    return tuple(found)


def has_leaves(layout: Any) -> bool:
    """Whether a memory layout holds any tensor (a memory of only empty sub-memories holds none)."""
    return any(key not in layout.nested or has_leaves(layout.nested[key]) for key in layout.keys)


def without_hollow(memory: TensorDictBase, hollow: tuple[tuple[tuple[str, ...], Any], ...]) -> TensorDictBase:
    """``memory`` without the sub-memories at the ``hollow`` paths (:func:`hollow_paths`); the same object if none."""
    for path, _ in hollow:
        memory = _edit(memory, path, None)
    return memory


def with_hollow(memory: TensorDictBase, hollow: tuple[tuple[tuple[str, ...], Any], ...]) -> TensorDictBase:
    """``memory`` with an empty sub-memory of the right layout at each ``hollow`` path where it has none."""
    for path, layout in hollow:
        memory = _edit(memory, path, layout)
    return memory


def _edit(memory: TensorDictBase, path: tuple[str, ...], layout: Any) -> TensorDictBase:
    """``memory`` without the node at ``path`` (``layout`` None) or with an empty one of ``layout`` where it has none.

    The nodes on the way are new TensorDicts; nothing is written into ``memory``.
    """
    entries = copy_entries(memory)
    key = path[0]
    if len(path) > 1:
        entries[key] = _edit(entries[key], path[1:], layout)
    elif layout is None:
        if key not in entries:
            return memory
        del entries[key]
    elif key in entries:
        return memory
    else:
        entries[key] = _empty(layout, memory.batch_size)
    return make_memory(entries, memory.batch_size)


def _empty(layout: Any, batch_size: torch.Size) -> TensorDict:
    return make_memory({key: _empty(layout.nested[key], batch_size) for key in layout.keys}, batch_size)
