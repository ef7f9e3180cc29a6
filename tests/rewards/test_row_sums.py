"""A row's reward does not depend on the batch it is evaluated in: the same bits alone, in a batch, offline.

Offline recomputation equal to the online step bit for bit rests on this. A matrix-vector product breaks it on
machines whose BLAS picks kernels by the number of rows (MKL on AVX-512), an ATen reduction over a last dim that
is not contiguous breaks it too; every row sum of the rewards goes through ``row_sum``.
"""

from __future__ import annotations

import pytest
import torch

from torchtasks.rewards.base import row_dot, squared_sum
from torchtasks.rewards.error import quadratic_form

SIZES = [1, 2, 3, 5, 8, 17, 33, 64]
ROWS = [1, 3, 64, 360]


def _layouts(x: torch.Tensor) -> dict[str, torch.Tensor]:
    """The same rows as a batch, a sliced view, a column-major copy and a [2, N/2, n] time-major block."""
    wide = torch.cat([x[:, :1], x, x[:, :2]], dim=-1)
    layouts = {"batch": x, "sliced": wide[:, 1 : 1 + x.shape[-1]], "column-major": x.t().contiguous().t()}
    if len(x) % 2 == 0:
        layouts["time-major"] = x.reshape(2, len(x) // 2, x.shape[-1])
    return layouts


FUNCTIONS = {
    "squared_sum": lambda x, w, m: squared_sum(x),
    "row_dot": lambda x, w, m: row_dot(x, w),
    "quadratic_form diagonal": lambda x, w, m: quadratic_form(w, x),
    "quadratic_form matrix": lambda x, w, m: quadratic_form(m, x),
}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_row_sums_to_the_same_bits_in_every_batch_and_layout(dtype):
    generator = torch.Generator().manual_seed(0)
    differ = []
    for n in SIZES:
        weight = torch.rand(n, dtype=dtype, generator=generator)
        matrix = torch.rand(n, n, dtype=dtype, generator=generator)
        for rows in ROWS:
            x = torch.randn(rows, n, dtype=dtype, generator=generator)
            for name, function in FUNCTIONS.items():
                alone = torch.stack([function(x[i : i + 1], weight, matrix)[0] for i in range(rows)])
                for layout, data in _layouts(x).items():
                    got = function(data, weight, matrix).reshape(-1)
                    if not torch.equal(got, alone):
                        differ.append((name, n, rows, layout))
    assert not differ, f"{len(differ)} cases round a row by its batch, e.g. {differ[:5]}"


def test_per_row_weights_sum_like_shared_ones():
    """Offline recomputation swaps per-frame weights in: a row's value must not change with that."""
    generator = torch.Generator().manual_seed(1)
    x = torch.randn(64, 17, dtype=torch.float32, generator=generator)
    weight = torch.rand(17, dtype=torch.float32, generator=generator)
    matrix = torch.rand(17, 17, dtype=torch.float32, generator=generator)
    assert torch.equal(row_dot(x, weight.expand(64, 17)), row_dot(x, weight))
    assert torch.equal(quadratic_form(weight.expand(64, 17), x, diagonal=True), quadratic_form(weight, x))
    assert torch.equal(quadratic_form(matrix.expand(64, 17, 17), x, diagonal=False), quadratic_form(matrix, x))
