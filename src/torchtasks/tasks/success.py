"""Success functions: map a batched state error to ``bool[*B]``."""

from __future__ import annotations

import functools
import inspect
import math
from collections.abc import Callable, Sequence

import numpy as np
import torch

from torchtasks._checks import check_finite_scalar, check_int, check_weight

__all__ = ["never_succeeded", "proximity_succeeded"]  # the checks below are for task constructors

_POSITIONAL = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)


def never_succeeded(error: torch.Tensor) -> torch.Tensor:
    """Return ``bool[*B]`` of False: a task that can only end by failure or time limit.

    Example:
        >>> import torch
        >>> never_succeeded(torch.zeros(2, 3))
        tensor([False, False])
    """
    return torch.zeros(error.shape[:-1], dtype=torch.bool, device=error.device)


def proximity_succeeded(error: torch.Tensor, threshold: float, dims: int | Sequence[int] | None = None) -> torch.Tensor:
    """Return ``bool[*B]``: whether the L2 norm of the error (or of ``error[..., dims]``) is below ``threshold``.

    The comparison is strict. Bind the threshold with :func:`functools.partial` to get a success
    function for a task.

    Args:
        error: state error ``[*B, n]``.
        threshold: distance below which the task is a success.
        dims: an index or a list of indices of the entries that count; ``None`` (or ``-1``, Pyrado's
            convention) for all entries.

    Example:
        >>> import torch
        >>> proximity_succeeded(torch.tensor([[0.03, 0.04], [0.3, 0.0]]), threshold=0.1)
        tensor([ True, False])
        >>> proximity_succeeded(torch.tensor([[0.0, 5.0]]), threshold=0.1, dims=0)
        tensor([True])
    """
    # a distance: finite and >= 0; a valid float passes with one comparison (this runs at every step)
    if not (type(threshold) is float and 0.0 <= threshold < math.inf) and not isinstance(threshold, torch.Tensor):
        check_weight(threshold, "threshold")
    size = error.shape[-1]  # a static fact: the checks below are host checks on Python ints
    if isinstance(dims, (int, np.integer)):  # one index (bools refused), -1 meaning all entries
        index = check_int(dims, "dims")
        if index != -1:
            _check_dim(index, size, "dims")
            error = error[..., index : index + 1]
    elif dims is not None:
        if isinstance(dims, (str, torch.Tensor, np.ndarray)) or not isinstance(dims, Sequence) or not dims:
            raise TypeError(f"dims must be an int, a non-empty list of ints or None, got {dims!r}")
        indices = [_check_dim(check_int(d, f"dims[{i}]"), size, f"dims[{i}]") for i, d in enumerate(dims)]
        error = error[..., indices]
    return torch.linalg.vector_norm(error, dim=-1) < threshold


def _check_dim(index: int, size: int, name: str) -> int:
    if not -size <= index < size:
        raise ValueError(f"{name}={index} is not an index of the error's {size} entries")
    return index


def _describe(fn: object) -> str:
    """A short name for a callable in error messages (the wrapped function of a partial)."""
    target = fn.func if isinstance(fn, functools.partial) else fn
    return getattr(target, "__qualname__", None) or type(target).__name__


def check_success_fn(success: object, name: str = "success") -> Callable[[torch.Tensor], torch.Tensor] | None:
    """Return ``success`` if it is ``None`` or can be called with the state error alone, else raise ``TypeError``.

    A success function is called as ``success(error)`` at every step; one whose other required
    arguments are not bound (``success=proximity_succeeded`` without a threshold) is refused here, at
    construction, naming the missing parameters, instead of failing at the first step. Callables
    whose signature Python cannot read (some builtins) are accepted as they are.

    Example:
        >>> import functools
        >>> check_success_fn(functools.partial(proximity_succeeded, threshold=0.1)) is not None
        True
        >>> try:
        ...     check_success_fn(proximity_succeeded)
        ... except TypeError as error:
        ...     print(str(error).split(", but ")[1].split(";")[0])
        proximity_succeeded has the required parameter(s) ['threshold'] left unbound
    """
    if success is None:
        return None
    if not callable(success):
        raise TypeError(f"{name} must be callable or None, got {type(success).__name__}")
    try:
        signature = inspect.signature(success)
    except (TypeError, ValueError):  # no readable signature: trust the caller
        return success  # type: ignore[return-value]
    parameters = list(signature.parameters.values())
    takes_error = any(p.kind in _POSITIONAL or p.kind == inspect.Parameter.VAR_POSITIONAL for p in parameters)
    required = [
        p.name
        for p in parameters
        if p.default is inspect.Parameter.empty
        and p.kind not in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    ]
    positional = [p for p in parameters if p.kind in _POSITIONAL]
    missing = [p for p in required if not (positional and p == positional[0].name)]
    if takes_error and not missing:
        return success  # type: ignore[return-value]
    described = _describe(success)
    example = "success=functools.partial(proximity_succeeded, threshold=0.1)"
    if not takes_error:
        problem = f"{described}{signature} takes no positional argument"
        fix = f"; give a function of the error, e.g. {example}"
    else:
        problem = f"{described} has the required parameter(s) {missing} left unbound"
        fix = f"; bind them, e.g. {example}, or give the task threshold=0.1 (DesiredStateTask)"
    raise TypeError(
        f"{name} must be callable with one positional argument (the state error [*B, n]), but {problem}{fix}"
    )


def proximity_success_fn(threshold: object, name: str = "threshold") -> Callable[[torch.Tensor], torch.Tensor]:
    """Return ``functools.partial(proximity_succeeded, threshold=threshold)`` for a positive finite threshold.

    What a task's ``threshold=`` shortcut means. A threshold that is not a real number is a ``TypeError``;
    one that is not finite and positive a ``ValueError``.

    Example:
        >>> import torch
        >>> success = proximity_success_fn(0.1)
        >>> success(torch.tensor([[0.03, 0.04], [0.3, 0.0]]))
        tensor([ True, False])
    """
    value = check_finite_scalar(threshold, name)
    if value <= 0:
        raise ValueError(f"{name} must be positive (a distance), got {value}")
    return functools.partial(proximity_succeeded, threshold=value)
