"""Argument checks shared by reward functions, tasks, transforms and envs.

Every check runs on shapes, dtypes and construction-time constants only, never on the values of
step inputs, so calling them inside a step costs a few Python comparisons and adds no host sync.

One helper per kind of argument, all with the same rules and messages (``<name> must be <kind>,
got <value> of type <type>``):

- integers (:func:`check_int`, :func:`check_positive_int`, :func:`check_non_negative_int`): a Python
  int or a NumPy integer, returned as a Python int; bools (also ``np.bool_``), floats (also integral
  ones such as ``2.0``), strings and tensors are a ``TypeError``, a value out of range a ``ValueError``;
- real numbers (:func:`check_finite_scalar`, :func:`check_weight`): any real number (Python or NumPy
  int or float, a one-element real tensor) except bools, returned as a Python float; other types are a
  ``TypeError``, NaN, infinities and (for weights) negative values a ``ValueError``;
- pairs (:func:`check_pair`): two real numbers ``(low, high)`` with ``low <= high`` (infinities
  allowed, NaN refused), returned as a tuple of Python floats.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import numpy as np
import torch

from torchtasks._did_you_mean import did_you_mean  # noqa: F401  (re-exported: one "did you mean")

FLOAT64 = torch.float64

#: floating dtypes that states, actions and errors may have (half precision is refused: an 11-bit
#: mantissa cannot hold rewards, bounds and thresholds faithfully, e.g. 1000.0 + 0.3 == 1000.0)
SUPPORTED_FLOATS = (torch.float32, torch.float64)


def as_constant(value: object, name: str, *, ndim: Sequence[int] | None = None) -> torch.Tensor:
    """Return ``value`` as a float64 tensor (a constant of the model), rejecting NaN.

    ``ndim`` lists the accepted numbers of dimensions.
    """
    check_real_numbers(value, name)
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


def check_real_numbers(value: object, name: str) -> None:
    """Refuse bools and complex numbers where real numbers are expected (a cast would turn them into 0/1 or drop
    the imaginary part); anything else is left to the conversion that follows."""
    if isinstance(value, torch.Tensor):
        kind = "bool" if value.dtype == torch.bool else "complex" if value.is_complex() else None
    else:
        try:
            array = np.asarray(value)
        except (TypeError, ValueError):  # ragged or odd: the conversion that follows says what is wrong
            return
        kind = {"b": "bool", "c": "complex"}.get(array.dtype.kind)
    if kind is not None:
        raise TypeError(f"{name} must hold real numbers, got {kind} values: {value!r}")


def _type_error(value: object, name: str, expected: str) -> TypeError:
    return TypeError(f"{name} must be {expected}, got {value!r} of type {type(value).__name__}")


def _is_int(value: object) -> bool:
    """Whether ``value`` is a Python int or a NumPy integer (not a bool)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _as_real(value: object, name: str) -> float:
    """``value`` as a float if it is a real number (not a bool), else ``TypeError``; NaN and inf pass."""
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        return float(value)
    if isinstance(value, torch.Tensor) and value.numel() == 1 and value.dtype != torch.bool and not value.is_complex():
        return float(value)
    raise _type_error(value, name, "a real number")


def check_finite_scalar(value: object, name: str) -> float:
    """Return ``value`` as a Python float; raise unless it is a finite real number.

    Accepted: Python and NumPy ints and floats (``np.float32(0.5)``), one-element real tensors.
    Bools, strings and other types are a ``TypeError``; NaN and infinities a ``ValueError``.
    """
    result = _as_real(value, name)
    if result != result or result in (math.inf, -math.inf):  # not math.isfinite: torch.compile traces this
        raise ValueError(f"{name} must be finite, got {result}")
    return result


def check_weight(value: object, name: str) -> float:
    """Return a finite, non-negative real number (a weight, a cost factor, a scale) as a Python float.

    Accepts what :func:`check_finite_scalar` accepts; a negative value is a ``ValueError``.
    """
    result = check_finite_scalar(value, name)
    if result < 0:
        raise ValueError(f"{name} must be non-negative, got {result}")
    return result


def check_pair(value: object, name: str) -> tuple[float, float]:
    """Return a ``(low, high)`` pair of Python floats with ``low <= high``.

    Each entry is a real number as for :func:`check_finite_scalar` (Python or NumPy, not a bool or a
    string); the pair is any iterable of exactly two (a tuple, a list, a 1-D array or tensor).
    Infinities are allowed (an open side); NaN is a ``ValueError``, as is ``low > high``.
    """
    expected = "a pair (low, high) of real numbers"
    if isinstance(value, (str, bytes)):
        raise _type_error(value, name, expected)
    try:
        entries = list(value)  # type: ignore[call-overload]
    except TypeError:
        raise _type_error(value, name, expected) from None
    if len(entries) != 2:
        raise _type_error(value, name, expected)
    try:
        low, high = (_as_real(entry, name) for entry in entries)
    except TypeError:
        raise _type_error(value, name, expected) from None
    if low != low or high != high:
        raise ValueError(f"{name} must not contain NaN, got {value!r}")
    if low > high:
        raise ValueError(f"{name} must satisfy low <= high, got {value!r}")
    return low, high


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


def check_int(value: object, name: str) -> int:
    """Return ``value`` as a Python int (any sign, e.g. an index counted from the end); raise unless it is an integer.

    Python ints and NumPy integers are accepted; bools, floats (also integral ones such as ``2.0``),
    strings and tensors are a ``TypeError``.
    """
    if not _is_int(value):
        raise _type_error(value, name, "an int")
    return int(value)  # type: ignore[call-overload]


def check_positive_int(value: object, name: str) -> int:
    """Return ``value`` as a Python int; raise unless it is an integer >= 1.

    Python ints and NumPy integers (``np.int64(2)``, e.g. from an array of sizes) are accepted; bools,
    floats (also integral ones such as ``2.0``) and strings are a ``TypeError``, values < 1 a ``ValueError``.
    """
    if not _is_int(value):
        raise _type_error(value, name, "a positive int")
    if value < 1:  # type: ignore[operator]
        raise ValueError(f"{name} must be a positive int, got {int(value)}")  # type: ignore[call-overload]
    return int(value)  # type: ignore[call-overload]


def check_non_negative_int(value: object, name: str) -> int:
    """Return ``value`` as a Python int; raise unless it is an integer >= 0 (a size that may be 0).

    Accepts and refuses the types :func:`check_positive_int` does; values < 0 are a ``ValueError``.
    """
    if not _is_int(value):
        raise _type_error(value, name, "a non-negative int")
    if value < 0:  # type: ignore[operator]
        raise ValueError(f"{name} must be a non-negative int, got {int(value)}")  # type: ignore[call-overload]
    return int(value)  # type: ignore[call-overload]


def check_batch_size(value: object, name: str) -> torch.Size:
    """Return ``value`` as a ``torch.Size``; raise unless it is a sequence of non-negative ints (a batch shape).

    Each entry is accepted as :func:`check_non_negative_int` accepts it; a string, a bare int or another type is a
    ``TypeError``.

    Example:
        >>> check_batch_size([4, 2], "batch_size")
        torch.Size([4, 2])
    """
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"{name} must be a torch.Size or a sequence of non-negative ints, got {value!r}")
    return torch.Size([check_non_negative_int(n, f"{name}[{i}]") for i, n in enumerate(value)])


def check_tensor(
    value: object, dtype: torch.dtype, shape: Sequence[int], subject: str, expected: str, shape_note: str = ""
) -> torch.Tensor:
    """Return ``value`` if it is a tensor of ``dtype`` and ``shape``; else a ``TypeError`` (not a tensor of ``dtype``)
    or a ``ValueError`` (another shape) saying ``"{subject} must be {expected}[{shape_note}], got ..."``.

    Example:
        >>> check_tensor(torch.zeros(2, 6, dtype=torch.float64), torch.float64, [2, 6], "delta", "float64 [2, 6]").shape
        torch.Size([2, 6])
        >>> check_tensor(torch.zeros(2, 6), torch.float64, [2, 6], "delta", "float64 [2, 6]")
        Traceback (most recent call last):
        ...
        TypeError: delta must be float64 [2, 6], got dtype torch.float32
    """
    if not isinstance(value, torch.Tensor) or value.dtype != dtype:
        got = f"dtype {value.dtype}" if isinstance(value, torch.Tensor) else f"a {type(value).__name__}"
        raise TypeError(f"{subject} must be {expected}, got {got}")
    if list(value.shape) != list(shape):
        raise ValueError(f"{subject} must be {expected}{shape_note}, got shape {list(value.shape)}")
    return value


def cast_like(constant: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Return ``constant`` in the dtype and on the device of ``x`` (a no-op when they already agree)."""
    if constant.dtype == x.dtype and constant.device == x.device:
        return constant
    return constant.to(device=x.device, dtype=x.dtype)
