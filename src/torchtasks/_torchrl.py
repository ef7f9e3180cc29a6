"""TorchRL-facing helpers shared by the transforms, the goal command and the episode statistics.

One copy each of: checking and unravelling a key argument (:func:`nested_key`, :func:`key_parts`),
listing keys in an error message (:func:`keys_text`), and finding the transforms of the env a
transform sits in (:func:`container_env`, :func:`flat_transforms`). This module knows TorchRL and
tensordict only, never the torchtasks transforms (which import it): a caller looking for a type,
e.g. the :class:`~torchtasks.transforms.TaskTransform`\\ s of an env, filters
:func:`flat_transforms` with ``isinstance`` itself.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from tensordict.utils import NestedKey, unravel_key
from torchrl.envs.transforms import Compose, Transform


def is_key(value: object) -> bool:
    """Whether ``value`` is a TensorDict key: a string, or a non-empty (nested) tuple of strings."""
    return isinstance(value, str) or (isinstance(value, tuple) and len(value) > 0 and all(map(is_key, value)))


def nested_key(value: object, name: str) -> NestedKey:
    """``value`` unravelled as a TensorDict key (a string or a tuple of strings), else ``TypeError`` naming ``name``.

    ``name`` is the argument as the message should name it, e.g. ``"TaskTransform: reward_key"``.
    Checked here because ``unravel_key(("a", 3))`` silently returns ``"a"``.
    """
    if not is_key(value):
        raise TypeError(
            f"{name} must be a key (a string or a tuple of strings), got {value!r} of type {type(value).__name__}"
        )
    return unravel_key(value)


def key_parts(key: NestedKey) -> tuple[str, ...]:
    """An unravelled key as a tuple of strings (``"a"`` -> ``("a",)``)."""
    return (key,) if isinstance(key, str) else tuple(key)


def keys_text(keys: Iterable[NestedKey]) -> str:
    """``keys`` as a sorted list of reprs (single quotes only, so a KeyError's message reads as written)."""
    return "[" + ", ".join(repr(key) for key in sorted(keys, key=str)) + "]"


def flat_transforms(transform: Transform) -> list[Transform]:
    """The leaf transforms of ``transform`` in order, nested ``Compose``\\ s flattened."""
    if isinstance(transform, Compose):
        return [leaf for child in transform.transforms for leaf in flat_transforms(child)]
    return [transform]


def container_env(transform: Transform) -> Any:
    """The env ``transform`` is in, or ``None`` (not in an env, e.g. a replay buffer's transform)."""
    try:
        return transform.container
    except (AttributeError, ValueError):
        return None
