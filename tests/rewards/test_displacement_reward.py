"""DisplacementReward: ``weight · (state[index] − origin)``, the difference taken first, as numpy computes it.

MO-Gymnasium's Hopper height objective is ``10 * info["z_distance_from_origin"]`` with
``z_distance_from_origin = qpos[1] - init_qpos[1]`` (float64). The expected values below are that numpy
expression; the product-first variant ``10 * a - 10 * b`` is shown to differ, so the order is what the test holds.
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import torch

from torchtasks.rewards import DisplacementReward

#: Hopper-v5's init_qpos[1] (the model's qpos0 of the torso height)
ORIGIN = 1.25


def test_value_is_numpys_weight_times_the_difference_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    heights = rng.uniform(0.5, 2.0, size=20_000)
    state = np.stack([rng.normal(size=heights.size), heights], axis=-1)
    expected = 10 * (state[:, 1] - ORIGIN)
    value = DisplacementReward(10.0, index=1, origin=ORIGIN)(torch.from_numpy(state), None)
    assert value.dtype == torch.float64
    assert np.array_equal(value.numpy(), expected)
    # the order matters: the product first rounds differently for some of these values
    assert np.count_nonzero(10 * state[:, 1] - 10 * ORIGIN != expected) > 0


def test_follows_the_state_dtype_and_ignores_the_action() -> None:
    reward = DisplacementReward(2.0, index=-1, origin=0.5)
    state = torch.tensor([[3.0, 1.5], [0.0, -0.5]])
    assert torch.equal(reward(state, torch.ones(2, 4)), torch.tensor([2.0, -2.0]))
    assert reward(state, None).dtype == torch.float32
    assert reward.uses_action is False and reward.stateful is False


def test_pickles_with_its_constants() -> None:
    reward = pickle.loads(pickle.dumps(DisplacementReward(10.0, index=1, origin=ORIGIN)))
    assert torch.equal(reward(torch.tensor([[0.0, 1.75]], dtype=torch.float64), None), torch.tensor([5.0]).double())


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"weight": math.inf}, ValueError, "weight must be finite"),
        ({"origin": math.nan}, ValueError, "origin must be finite"),
        ({"origin": "1.0"}, TypeError, "origin"),
        ({"index": 1.0}, TypeError, "index"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        DisplacementReward(**kwargs)
