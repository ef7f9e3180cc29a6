"""Argument checks shared by reward functions and tasks.

Every check runs on shapes, dtypes and construction-time constants only, never on the values of
step inputs, so calling them inside a step costs a few Python comparisons and adds no host sync.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

FLOAT64 = torch.float64

#: floating dtypes that states, actions and errors may have (half precision is refused: an 11-bit
#: mantissa cannot hold rewards, bounds and thresholds faithfully, e.g. 1000.0 + 0.3 == 1000.0)
SUPPORTED_FLOATS = (torch.float32, torch.float64)


def as_constant(value: object, name: str, *, ndim: Sequence[int] | None = None) -> torch.Tensor:
    """Return ``value`` as a float64 tensor (a constant of the model), rejecting NaN.

    ``ndim`` lists the accepted numbers of dimensions.
    """
    if isinstance(value, torch.Tensor):
        tensor = value.detach().to(dtype=FLOAT64).clone()
    else:
        try:
            tensor = torch.as_tensor(value, dtype=FLOAT64).clone()
        except (TypeError, ValueError, RuntimeError) as error:
            raise TypeError(f"{name} must be a number or an array of numbers, got {value!r}") from error
    if ndim is not None and tensor.ndim not in ndim:
        expected = " or ".join(f"{n}-D" for n in ndim)
        raise ValueError(f"{name} must be {expected}, got shape {tuple(tensor.shape)}")
    if torch.isnan(tensor).any():
        raise ValueError(f"{name} must not contain NaN, got {tensor.tolist()}")
    return tensor


def check_finite_scalar(value: object, name: str) -> float:
    """Return ``value`` as a float; raise if it is not a finite real number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        if isinstance(value, torch.Tensor) and value.numel() == 1:
            value = float(value)
        else:
            raise TypeError(f"{name} must be a real number, got {value!r} of type {type(value).__name__}")
    value = float(value)
    if value != value or value in (float("inf"), float("-inf")):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def check_input(x: object, name: str, size: int | None = None) -> torch.Tensor:
    """Check that ``x`` is a floating tensor ``[*B, size]`` and return it."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor of shape [*B, {size or 'n'}], got {type(x).__name__}")
    if x.dtype not in SUPPORTED_FLOATS:
        detail = "half precision is not supported; " if x.is_floating_point() else ""
        raise TypeError(f"{name} must be a float32 or float64 tensor ({detail}cast it first), got dtype {x.dtype}")
    if x.ndim == 0:
        raise ValueError(f"{name} must have shape [*B, {size or 'n'}], got a 0-d tensor")
    if size is not None and x.shape[-1] != size:
        raise ValueError(f"{name} must have shape [*B, {size}], got {tuple(x.shape)}")
    return x


def check_same_batch(a: torch.Tensor, b: torch.Tensor, name_a: str, name_b: str) -> None:
    """Raise unless ``a`` and ``b`` have the same leading batch shape (no silent broadcasting)."""
    if a.shape[:-1] != b.shape[:-1]:
        raise ValueError(
            f"{name_a} and {name_b} must have the same batch shape, got {tuple(a.shape)} and {tuple(b.shape)}"
        )


def check_index(index: object, name: str) -> int:
    """Return ``index`` as an int, rejecting bools and non-integers."""
    if isinstance(index, bool) or not isinstance(index, int):
        raise TypeError(f"{name} must be an int, got {index!r}")
    return index


def check_positive_int(value: object, name: str) -> int:
    """Return ``value`` as a Python int; raise unless it is an integer >= 1.

    Python ints and NumPy integers (``np.int64(2)``, e.g. from an array of sizes) are accepted; bools,
    floats (also integral ones such as ``2.0``) and strings are not.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be a positive int, got {value!r} of type {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name} must be a positive int, got {value!r}")
    return int(value)


def cast_like(constant: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Return ``constant`` in the dtype and on the device of ``x`` (a no-op when they already agree)."""
    if constant.dtype == x.dtype and constant.device == x.device:
        return constant
    return constant.to(device=x.device, dtype=x.dtype)
