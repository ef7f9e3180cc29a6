"""Success functions: map a batched state error to ``bool[*B]``."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from torchtasks._checks import check_int

__all__ = ["never_succeeded", "proximity_succeeded"]


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
    if isinstance(dims, (int, np.integer)):  # one index (bools refused), -1 meaning all entries
        index = check_int(dims, "dims")
        if index != -1:
            error = error[..., index : index + 1]
    elif dims is not None:
        error = error[..., list(dims)]
    return torch.linalg.vector_norm(error, dim=-1) < threshold
