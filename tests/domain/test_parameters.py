"""The domain parameters (torchtasks.domain.parameters): Pyrado's four distributions, their clipping and rounding,
per-env rows, the support a draw can reach, the env field they bind to, and the one check every written or loaded
value passes.

Expected numbers are written here from the distributions' formulas (moments, standard errors, Pyrado's
``torch.clamp`` then ``torch.round``), never taken from the code under test.
"""

from __future__ import annotations

import math

import pytest
import torch

from torchtasks.domain import (
    BernoulliDomainParam,
    DomainField,
    DomainParam,
    MultivariateNormalDomainParam,
    NormalDomainParam,
    UniformDomainParam,
)

F64 = torch.float64
NAME = "body_mass:torso"

#: each kind with the distribution's arguments (value shape [2])
KINDS = {
    "uniform": (UniformDomainParam, ([1.0, -2.0], [0.5, 2.0])),
    "normal": (NormalDomainParam, ([1.0, -2.0], [0.5, 2.0])),
    "mvn": (MultivariateNormalDomainParam, ([1.0, -2.0], [[1.0, 0.6], [0.6, 2.0]])),
    "bernoulli": (BernoulliDomainParam, ([0.0, 1.0], [1.0, 5.0], [0.3, 0.8])),
}
#: clipping bounds strictly inside every element's range of draws (so both bounds are reached)
CLIPS = {
    "uniform": ([0.7, -3.0], [1.2, -0.5]),
    "normal": ([0.7, -3.0], [1.2, -0.5]),
    "mvn": ([0.7, -3.0], [1.2, -0.5]),
    "bernoulli": ([0.2, 2.0], [0.9, 4.5]),
}
#: three envs' own arguments per kind (for per-env parameters)
ENV_ARGS = {
    "uniform": [([1.0, -2.0], [0.5, 2.0]), ([10.0, 20.0], [1.0, 0.0]), ([-5.0, 0.0], [0.0, 3.0])],
    "normal": [([1.0, -2.0], [0.5, 2.0]), ([10.0, 20.0], [1.0, 0.0]), ([-5.0, 0.0], [0.0, 3.0])],
    "mvn": [
        ([1.0, -2.0], [[1.0, 0.6], [0.6, 2.0]]),
        ([10.0, 20.0], [[0.1, 0.0], [0.0, 5.0]]),
        ([-5.0, 0.0], [[4.0, -1.9], [-1.9, 1.0]]),
    ],
    "bernoulli": [
        ([0.0, 1.0], [1.0, 5.0], [0.3, 0.8]),
        ([7.0, 7.0], [8.0, 9.0], [1.0, 0.0]),
        ([-1.0, 2.0], [1.0, -2.0], [0.5, 0.5]),
    ],
}


def build(kind: str, args: tuple | None = None, **kwargs) -> DomainParam:
    cls, default = KINDS[kind]
    return cls(NAME, *(default if args is None else args), **kwargs)


def generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def field(shape=(2,), low=-10.0, high=10.0, low_open=False, name="test_field") -> DomainField:
    return DomainField(
        name, torch.Size(shape), torch.zeros(shape, dtype=F64), low, high, low_open, ("f",), False, "a test field"
    )


MASS = DomainField(
    NAME, torch.Size([]), torch.tensor(3.5, dtype=F64), 0.0, math.inf, True, ("body_mass",), True, "mass (kg)"
)


def state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {key: value.clone() for key, value in module.state_dict().items()}


def assert_same_state(module: torch.nn.Module, before: dict[str, torch.Tensor]) -> None:
    after = module.state_dict()
    assert after.keys() == before.keys()
    for key, value in before.items():
        assert after[key].shape == value.shape, key
        assert torch.equal(after[key], value), key


# --------------------------------------------------------------------------------- layout
@pytest.mark.parametrize("kind", KINDS)
def test_buffers_are_the_distribution_fields_in_float64(kind):
    param = build(kind)
    names = [name for name, _ in param.named_buffers()]
    assert tuple(names) == type(param).distribution_fields
    assert all(buffer.dtype == F64 for buffer in param.buffers())
    assert param.value_shape == torch.Size([2])
    assert param.sample(5, generator(0)).shape == (5, 2)


def test_distribution_fields_per_kind():
    assert UniformDomainParam.distribution_fields == ("mean", "halfspan", "clip_lo", "clip_up")
    assert NormalDomainParam.distribution_fields == ("mean", "std", "clip_lo", "clip_up")
    assert MultivariateNormalDomainParam.distribution_fields == ("mean", "cov", "clip_lo", "clip_up")
    assert BernoulliDomainParam.distribution_fields == ("val_0", "val_1", "prob_1", "clip_lo", "clip_up")


def test_a_number_applies_to_every_element_and_scalars_have_shape_empty():
    param = UniformDomainParam(NAME, torch.tensor([1.0, 2.0, 3.0]), 0.5, clip_lo=0.0)
    assert param.halfspan.tolist() == [0.5, 0.5, 0.5] and param.clip_lo.tolist() == [0.0, 0.0, 0.0]
    scalar = NormalDomainParam(NAME, 3.5, 0.1)
    assert scalar.value_shape == torch.Size([]) and scalar.sample(4, generator(0)).shape == (4,)


def test_repr():
    assert repr(UniformDomainParam(NAME, 3.5, 0.5)) == "UniformDomainParam('body_mass:torso', mean=3.5, halfspan=0.5)"
    assert (
        repr(BernoulliDomainParam("gravity", [0.0, 1.0], 2.0, 0.5, clip_up=1.5, roundint=True))
        == "BernoulliDomainParam('gravity', val_0=[0.0, 1.0], val_1=[2.0, 2.0], prob_1=[0.5, 0.5], "
        "clip_up=[1.5, 1.5], roundint=True)"
    )


# -------------------------------------------------------------------------------- moments
N_MOMENTS = 200_000


def expected_moments(kind: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The mean, the covariance, and Var[(x_i - mu_i)(x_j - mu_j)] (the variance of one covariance term)."""
    if kind == "uniform":
        mean, half = torch.tensor([1.0, -2.0], dtype=F64), torch.tensor([0.5, 2.0], dtype=F64)
        var, fourth = half**2 / 3, half**4 / 5  # U[m-h, m+h]: variance h^2/3, 4th central moment h^4/5
        cov = torch.diag(var)
        term_var = torch.outer(var, var)  # independent elements: Var[XY] = var_x var_y
        term_var.diagonal().copy_(fourth - var**2)
    elif kind == "normal":
        mean, std = torch.tensor([1.0, -2.0], dtype=F64), torch.tensor([0.5, 2.0], dtype=F64)
        var = std**2
        cov = torch.diag(var)
        term_var = torch.outer(var, var)
        term_var.diagonal().copy_(2 * var**2)  # 3 sigma^4 - sigma^4
    elif kind == "mvn":
        mean = torch.tensor([1.0, -2.0], dtype=F64)
        cov = torch.tensor([[1.0, 0.6], [0.6, 2.0]], dtype=F64)
        term_var = torch.outer(cov.diagonal(), cov.diagonal()) + cov**2  # Isserlis: S_ii S_jj + S_ij^2
    else:
        val_0, val_1 = torch.tensor([0.0, 1.0], dtype=F64), torch.tensor([1.0, 5.0], dtype=F64)
        p = torch.tensor([0.3, 0.8], dtype=F64)
        d = val_1 - val_0
        mean = val_0 + p * d
        var = p * (1 - p) * d**2
        cov = torch.diag(var)
        term_var = torch.outer(var, var)
        term_var.diagonal().copy_(p * (1 - p) * (1 - 2 * p) ** 2 * d**4)  # (x - mu)^2 takes two values
    return mean, cov, term_var


@pytest.mark.parametrize("kind", KINDS)
def test_moments_of_many_draws_match_the_formulas(kind):
    draws = build(kind).sample(N_MOMENTS, generator(1234))
    mean, cov, term_var = expected_moments(kind)
    sample_mean = draws.mean(0)
    centred = draws - sample_mean
    sample_cov = centred.T @ centred / (N_MOMENTS - 1)
    mean_tolerance = 5 * (cov.diagonal() / N_MOMENTS).sqrt()
    cov_tolerance = 5 * (term_var / N_MOMENTS).sqrt()
    assert ((sample_mean - mean).abs() <= mean_tolerance).all(), (sample_mean, mean)
    assert ((sample_cov - cov).abs() <= cov_tolerance).all(), (sample_cov, cov)


def test_bernoulli_draws_val_1_with_frequency_prob_1_and_nothing_else():
    draws = build("bernoulli").sample(N_MOMENTS, generator(99))
    val_0, val_1, p = torch.tensor([0.0, 1.0]), torch.tensor([1.0, 5.0]), torch.tensor([0.3, 0.8])
    is_1, is_0 = draws == val_1.to(F64), draws == val_0.to(F64)
    assert (is_0 | is_1).all()
    frequency = is_1.to(F64).mean(0)
    assert ((frequency - p.to(F64)).abs() <= 5 * (p * (1 - p) / N_MOMENTS).sqrt()).all(), frequency


@pytest.mark.parametrize(
    ("kind", "args"),
    [("uniform", ([1.0, -2.0], 0.0)), ("normal", ([1.0, -2.0], 0.0)), ("bernoulli", ([1.0, -2.0], [5.0, 5.0], 0.0))],
)
def test_zero_spread_draws_the_mean(kind, args):
    """A halfspan or std of 0 (a curriculum's start) draws the nominal value (an MVN's cov must stay definite)."""
    draws = build(kind, args).sample(100, generator(0))
    assert torch.equal(draws, torch.tensor([[1.0, -2.0]] * 100, dtype=F64))


# ------------------------------------------------------------------------- clip and round
@pytest.mark.parametrize("roundint", [False, True])
@pytest.mark.parametrize("kind", KINDS)
def test_clip_then_round_is_pyrados_formula(kind, roundint):
    clip_lo, clip_up = CLIPS[kind]
    raw = build(kind).sample(5000, generator(5))
    post = build(kind, clip_lo=clip_lo, clip_up=clip_up, roundint=roundint).sample(5000, generator(5))
    low, up = torch.tensor(clip_lo, dtype=F64), torch.tensor(clip_up, dtype=F64)
    expected = torch.clamp(raw, low, up)  # Pyrado's DomainParam.sample: clamp, then round
    if roundint:
        expected = torch.round(expected)
    assert (raw < low).any(dim=0).all() and (raw > up).any(dim=0).all()  # both bounds cut every element
    assert post.dtype == F64
    assert torch.equal(post, expected)


# --------------------------------------------------------------------------------- seeds
@pytest.mark.parametrize("kind", KINDS)
def test_seeded_draws_repeat_and_seeds_differ(kind):
    param = build(kind)
    first, again = param.sample(1000, generator(3)), param.sample(1000, generator(3))
    other = param.sample(1000, generator(4))
    assert torch.equal(first, again)
    assert not torch.equal(first, other)


def test_global_generator_is_used_without_one():
    param = build("normal")
    torch.manual_seed(11)
    first = param.sample(10)
    torch.manual_seed(11)
    assert torch.equal(first, param.sample(10))


@pytest.mark.parametrize("kind", KINDS)
def test_the_generator_advances_by_the_number_of_draws_only(kind):
    """Different parameter values, clipping, rounding or per-env rows leave the generator in the same state."""
    variants = [build(kind), build(kind, ENV_ARGS[kind][1]), build(kind, clip_lo=CLIPS[kind][0], roundint=True)]
    per_env = build(kind)
    per_env.use_per_env(torch.Size([64]))
    variants.append(per_env)
    states = []
    for param in variants:
        g = generator(8)
        param.sample(64, g)
        states.append(g.get_state())
    assert all(torch.equal(s, states[0]) for s in states)
    fresh = generator(8)
    assert not torch.equal(fresh.get_state(), states[0])


# ------------------------------------------------------------------------------- per env
def write_rows(param: DomainParam, rows: list[tuple]) -> None:
    """Give env i (row-major) the distribution arguments ``rows[i]``."""
    for i, args in enumerate(rows):
        for name, value in zip(param.distribution_fields, args, strict=False):
            row = torch.tensor(value, dtype=F64)
            param._buffers[name].view(-1, *row.shape)[i] = row


@pytest.mark.parametrize("batch", [(3,), (1, 3)])
@pytest.mark.parametrize("kind", KINDS)
def test_per_env_rows_draw_from_their_own_distribution(kind, batch):
    """Env i's value equals what a shared parameter with env i's arguments draws at row i of the same stream."""
    param = build(kind, clip_lo=CLIPS[kind][0])
    param.use_per_env(torch.Size(batch))
    assert all(b.shape[: len(batch)] == batch for b in param.buffers())
    write_rows(param, ENV_ARGS[kind])
    draws = param.sample(3, generator(21))
    assert draws.shape == (3, 2)
    for i, args in enumerate(ENV_ARGS[kind]):
        alone = build(kind, args, clip_lo=CLIPS[kind][0]).sample(3, generator(21))[i]
        torch.testing.assert_close(draws[i], alone, rtol=1e-12, atol=1e-12)


def test_per_env_rows_hold_far_apart_values():
    param = build("uniform")
    param.use_per_env(torch.Size([3]))
    write_rows(param, ENV_ARGS["uniform"])
    draws = torch.stack([param.sample(3, generator(s)) for s in range(200)])  # [200, 3, 2]
    for i, (mean, half) in enumerate(ENV_ARGS["uniform"]):
        low, high = (
            torch.tensor(mean, dtype=F64) - torch.tensor(half),
            torch.tensor(mean, dtype=F64) + torch.tensor(half),
        )
        assert ((draws[:, i] >= low) & (draws[:, i] <= high)).all()


@pytest.mark.parametrize("kind", KINDS)
def test_use_per_env_starts_from_current_values_is_idempotent_and_refuses_another_batch(kind):
    param = build(kind)
    shared = state(param)
    param.use_per_env(torch.Size([4]))
    for name, value in shared.items():
        assert torch.equal(param._buffers[name], value.expand(4, *value.shape))
    param._buffers[param.distribution_fields[0]][1] += 1.0
    per_env = state(param)
    param.use_per_env([4])
    assert_same_state(param, per_env)
    with pytest.raises(ValueError, match=r"neither shared \[2\] nor the requested per-env shape \[5, 2\]"):
        param.use_per_env([5])
    with pytest.raises(ValueError, match=r"num must be the number of envs, 4 .*got 3"):
        param.sample(3, generator(0))
    with pytest.raises(TypeError, match="batch"):
        param.use_per_env(4)


# ------------------------------------------------------------------------------- support
UNCLIPPED_SUPPORT = {
    "uniform": ([0.5, -4.0], [1.5, 0.0]),
    "normal": ([-math.inf, -math.inf], [math.inf, math.inf]),
    "mvn": ([-math.inf, -math.inf], [math.inf, math.inf]),
    "bernoulli": ([0.0, 1.0], [1.0, 5.0]),
}


@pytest.mark.parametrize("kind", KINDS)
def test_support_without_clipping(kind):
    low, high = build(kind).support()
    assert low.tolist() == UNCLIPPED_SUPPORT[kind][0] and high.tolist() == UNCLIPPED_SUPPORT[kind][1]


@pytest.mark.parametrize("roundint", [False, True])
@pytest.mark.parametrize("kind", KINDS)
def test_support_holds_every_draw_and_clipping_attains_it(kind, roundint):
    clip_lo, clip_up = (torch.tensor(bound, dtype=F64) for bound in CLIPS[kind])
    param = build(kind, clip_lo=clip_lo, clip_up=clip_up, roundint=roundint)
    low, high = param.support()
    expected = (torch.round(clip_lo), torch.round(clip_up)) if roundint else (clip_lo, clip_up)
    assert torch.equal(low, expected[0]) and torch.equal(high, expected[1])
    draws = param.sample(10_000, generator(2))
    assert ((draws >= low) & (draws <= high)).all()
    assert torch.equal(draws.min(0).values, low) and torch.equal(draws.max(0).values, high)


@pytest.mark.parametrize("kind", KINDS)
def test_support_per_env_has_one_row_per_env(kind):
    param = build(kind)
    param.use_per_env(torch.Size([3]))
    write_rows(param, ENV_ARGS[kind])
    low, high = param.support()
    assert low.shape == high.shape == (3, 2)
    for i, args in enumerate(ENV_ARGS[kind]):
        alone_low, alone_high = build(kind, args).support()
        assert torch.equal(low[i], alone_low) and torch.equal(high[i], alone_high)


# ---------------------------------------------------------------------------- env fields
#: per kind: whether the unclipped parameter stays in [-10, 10], and arguments that leave it
BINDING = {
    "uniform": (True, ([1.0, -2.0], [0.5, 9.0])),
    "normal": (False, None),
    "mvn": (False, None),
    "bernoulli": (True, ([0.0, 1.0], [1.0, 11.0], [0.3, 0.8])),
}


@pytest.mark.parametrize("kind", KINDS)
def test_bind_field_accepts_a_support_inside_and_refuses_one_outside(kind):
    inside, leaving = BINDING[kind]
    target = field()
    if inside:
        build(kind).bind_field(target)
    else:
        with pytest.raises(ValueError, match=r"can write -inf into 'test_field' \(a test field\)"):
            build(kind).bind_field(target)
    build(kind, clip_lo=-10.0, clip_up=10.0).bind_field(target)
    if leaving is not None:  # a bounded distribution reaching past the field
        with pytest.raises(ValueError, match=r"can write (-11.0|11.0) into 'test_field'"):
            build(kind, leaving).bind_field(target)
    else:  # an unbounded one clipped past the field
        with pytest.raises(ValueError, match=r"can write 11.0 into 'test_field'"):
            build(kind, clip_lo=-10.0, clip_up=11.0).bind_field(target)


@pytest.mark.parametrize("kind", KINDS)
def test_bind_field_refuses_another_value_shape(kind):
    with pytest.raises(ValueError, match=r"shape \[2\].*'test_field' \(a test field\) has values of shape \[3\]"):
        build(kind).bind_field(field(shape=(3,)))
    with pytest.raises(TypeError, match="DomainField"):
        build(kind).bind_field("test_field")


def test_bind_field_refuses_a_mass_that_can_reach_zero():
    UniformDomainParam(NAME, 3.5, 3.0).bind_field(MASS)
    with pytest.raises(ValueError, match=r"can write 0.0 into 'body_mass:torso'.*must be in \(0.0, inf\)"):
        UniformDomainParam(NAME, 3.5, 3.5).bind_field(MASS)
    with pytest.raises(ValueError, match=r"can write 0.0"):  # clip to 0.5, then rounding (half to even) gives 0
        UniformDomainParam(NAME, 3.5, 3.0, clip_lo=0.4, roundint=True).bind_field(MASS)
    NormalDomainParam(NAME, 3.5, 1.0, clip_lo=0.1).bind_field(MASS)


# ------------------------------------------------------------------ construction refusals
def uniform(mean=(1.0, 2.0), halfspan=0.5, **kwargs):
    return lambda: UniformDomainParam(NAME, list(mean) if isinstance(mean, tuple) else mean, halfspan, **kwargs)


REFUSED = [
    ("name with a dot", lambda: UniformDomainParam("body_mass.torso", 1.0, 0.5), ValueError, "'.' or '/'"),
    ("name with a slash", lambda: UniformDomainParam("a/b", 1.0, 0.5), ValueError, "'.' or '/'"),
    ("empty name", lambda: UniformDomainParam("", 1.0, 0.5), ValueError, "non-empty string"),
    ("name not a string", lambda: UniformDomainParam(3, 1.0, 0.5), ValueError, "non-empty string"),
    ("roundint not a bool", uniform(roundint=1), TypeError, "roundint must be a bool"),
    ("negative halfspan", uniform(halfspan=-0.5), ValueError, r"halfspan must be >= 0, got \[-0.5, -0.5\]"),
    ("one negative halfspan", uniform(halfspan=torch.tensor([0.5, -1.0])), ValueError, "halfspan must be >= 0"),
    ("NaN mean", uniform(mean=(1.0, math.nan)), ValueError, "mean must not contain NaN"),
    ("NaN halfspan", uniform(halfspan=math.nan), ValueError, "halfspan must not be NaN"),
    ("infinite mean", uniform(mean=(1.0, math.inf)), ValueError, "mean must be finite"),
    ("infinite halfspan", uniform(halfspan=math.inf), ValueError, "halfspan must be finite"),
    ("mean + halfspan overflows", uniform(mean=(1e308, 0.0), halfspan=1e308), ValueError, r"mean \+ halfspan must be"),
    ("bool mean", uniform(mean=True), TypeError, "mean must be a real number"),
    ("bool halfspan", uniform(halfspan=True), TypeError, "halfspan must be a real number"),
    ("bool tensor halfspan", uniform(halfspan=torch.tensor([True, False])), TypeError, "real numbers, got bool"),
    (
        "halfspan of another shape",
        uniform(halfspan=torch.tensor([0.5, 0.5, 0.5])),
        ValueError,
        r"halfspan must be a number or a tensor of shape \[2\] \(from mean's shape\), got shape \[3\]",
    ),
    ("halfspan 0-d tensor", uniform(halfspan=torch.tensor(0.5)), ValueError, r"shape \[2\].*got shape \[\]"),
    ("clip_lo above clip_up", uniform(clip_lo=2.0, clip_up=1.0), ValueError, "clip_lo=2.0 > clip_up=1.0"),
    ("clip_lo inf", uniform(clip_lo=math.inf), ValueError, "clip_lo must be below inf"),
    ("clip_up -inf", uniform(clip_up=-math.inf), ValueError, "clip_up must be above -inf"),
    ("clip_lo NaN", uniform(clip_lo=math.nan), ValueError, "clip_lo must not be NaN"),
    ("clip_up of another shape", uniform(clip_up=[1.0]), ValueError, r"clip_up must be .* shape \[2\]"),
    ("clip_lo bool", uniform(clip_lo=False), TypeError, "clip_lo must be a real number"),
    ("negative std", lambda: NormalDomainParam(NAME, 1.0, -0.1), ValueError, "std must be >= 0, got -0.1"),
    ("infinite std", lambda: NormalDomainParam(NAME, 1.0, math.inf), ValueError, "std must be finite"),
    ("NaN std", lambda: NormalDomainParam(NAME, 1.0, math.nan), ValueError, "std must not be NaN"),
    ("infinite normal mean", lambda: NormalDomainParam(NAME, -math.inf, 1.0), ValueError, "mean must be finite"),
    ("std string", lambda: NormalDomainParam(NAME, 1.0, "wide"), TypeError, "std must be a number"),
    (
        "mvn scalar mean",
        lambda: MultivariateNormalDomainParam(NAME, 1.0, [[1.0]]),
        ValueError,
        r"mean must be a vector \[d\] with d >= 1, got shape \[\]",
    ),
    (
        "mvn matrix mean",
        lambda: MultivariateNormalDomainParam(NAME, [[1.0]], [[1.0]]),
        ValueError,
        r"got shape \[1, 1\]",
    ),
    ("mvn empty mean", lambda: MultivariateNormalDomainParam(NAME, [], []), ValueError, r"d >= 1, got shape \[0\]"),
    (
        "mvn cov of another shape",
        lambda: MultivariateNormalDomainParam(NAME, [1.0, 2.0], torch.eye(3)),
        ValueError,
        r"cov must be a number or a tensor of shape \[2, 2\].*got shape \[3, 3\]",
    ),
    (
        "mvn cov vector",
        lambda: MultivariateNormalDomainParam(NAME, [1.0, 2.0], [1.0, 1.0]),
        ValueError,
        r"shape \[2, 2\].*got shape \[2\]",
    ),
    (
        "mvn cov not symmetric",
        lambda: MultivariateNormalDomainParam(NAME, [1.0, 2.0], [[1.0, 0.5], [0.4, 1.0]]),
        ValueError,
        "cov must be symmetric",
    ),
    (
        "mvn cov indefinite",
        lambda: MultivariateNormalDomainParam(NAME, [1.0, 2.0], [[1.0, 2.0], [2.0, 1.0]]),
        ValueError,
        "cov must be positive definite",
    ),
    (
        "mvn cov zero",
        lambda: MultivariateNormalDomainParam(NAME, [1.0, 2.0], 0.0),
        ValueError,
        "cov must be positive definite",
    ),
    (
        "mvn cov infinite",
        lambda: MultivariateNormalDomainParam(NAME, [1.0, 2.0], [[math.inf, 0.0], [0.0, 1.0]]),
        ValueError,
        "cov must be finite",
    ),
    ("prob_1 above 1", lambda: BernoulliDomainParam(NAME, 0.0, 1.0, 1.5), ValueError, r"prob_1 must be in \[0, 1\]"),
    ("prob_1 below 0", lambda: BernoulliDomainParam(NAME, 0.0, 1.0, -0.1), ValueError, r"prob_1 must be in \[0, 1\]"),
    ("prob_1 bool", lambda: BernoulliDomainParam(NAME, 0.0, 1.0, True), TypeError, "prob_1 must be a real number"),
    ("val_1 infinite", lambda: BernoulliDomainParam(NAME, 0.0, math.inf, 0.5), ValueError, "val_1 must be finite"),
    ("val_0 NaN", lambda: BernoulliDomainParam(NAME, math.nan, 1.0, 0.5), ValueError, "val_0 must not contain NaN"),
    (
        "val_1 of another shape",
        lambda: BernoulliDomainParam(NAME, [0.0, 0.0], [1.0, 1.0, 1.0], 0.5),
        ValueError,
        r"val_1 must be a number or a tensor of shape \[2\] \(from val_0's shape\), got shape \[3\]",
    ),
]


@pytest.mark.parametrize(("build_it", "error", "message"), [case[1:] for case in REFUSED], ids=[c[0] for c in REFUSED])
def test_construction_refuses(build_it, error, message):
    with pytest.raises(error, match=message):
        build_it()


@pytest.mark.parametrize("kind", KINDS)
def test_construction_accepts_zero_spread_and_infinite_clips(kind):
    param = build(kind, clip_lo=-math.inf, clip_up=math.inf)
    assert torch.isinf(param.clip_lo).all() and torch.isinf(param.clip_up).all()
    UniformDomainParam(NAME, 3.5, 0.0)
    NormalDomainParam(NAME, 3.5, 0.0)
    BernoulliDomainParam(NAME, 3.5, 4.0, 0.0)
    BernoulliDomainParam(NAME, 3.5, 4.0, 1.0)


# ---------------------------------------------------------------------- written values
WRITE_REFUSED = [
    ("uniform", "halfspan", torch.tensor([0.5, -0.5]), "halfspan must be >= 0"),
    ("uniform", "halfspan", torch.tensor([[0.5, 0.5], [-1.0, 0.0]]), "halfspan must be >= 0"),
    ("uniform", "mean", torch.tensor([math.nan, 1.0]), "mean must not be NaN"),
    ("uniform", "mean", torch.tensor([math.inf, 1.0]), "mean must be finite"),
    ("normal", "std", torch.tensor([-1.0, 1.0]), "std must be >= 0"),
    ("mvn", "cov", torch.tensor([[1.0, 2.0], [2.0, 1.0]]), "cov must be positive definite"),
    ("mvn", "cov", torch.tensor([[1.0, 0.5], [0.0, 1.0]]), "cov must be symmetric"),
    ("bernoulli", "prob_1", torch.tensor([1.5, 0.5]), r"prob_1 must be in \[0, 1\]"),
    ("bernoulli", "val_0", torch.tensor([-math.inf, 0.0]), "val_0 must be finite"),
    ("normal", "clip_lo", torch.tensor([3.0, 3.0]), "clip_lo=3.0 > clip_up=2.0"),
    ("bernoulli", "clip_up", torch.tensor([[3.0, 3.0], [-4.0, 3.0]]), "clip_lo=-3.0 > clip_up=-4.0"),
]


@pytest.mark.parametrize("per_env", [False, True], ids=["shared", "per_env"])
@pytest.mark.parametrize(("kind", "buffer", "value", "message"), WRITE_REFUSED)
def test_check_written_value_refuses_what_the_constructor_refuses(kind, buffer, value, message, per_env):
    param = build(kind, clip_lo=-3.0, clip_up=2.0)
    if per_env:
        param.use_per_env(torch.Size([3]))
    before = state(param)
    with pytest.raises(ValueError, match=message) as error:
        param.check_written_value(buffer, value, "the schedule of 'domain.x'")
    text = str(error.value)
    assert text.startswith("the schedule of 'domain.x' can write ")
    assert f"'s {buffer}, which it refuses" in text
    assert_same_state(param, before)


@pytest.mark.parametrize("kind", KINDS)
def test_check_written_value_accepts_the_three_forms(kind):
    param = build(kind)
    param.use_per_env(torch.Size([3]))
    name = param.distribution_fields[0]
    row = param._buffers[name][0].clone()
    param.check_written_value(name, row, "a row")
    param.check_written_value(name, torch.stack([row, row + 1]), "two rows")
    param.check_written_value(name, param._buffers[name].clone().float(), "the whole buffer")


@pytest.mark.parametrize("kind", KINDS)
def test_check_written_value_refuses_shapes_names_and_types(kind):
    param = build(kind)
    name = param.distribution_fields[0]
    with pytest.raises(ValueError, match=r"a table: the value written into .* must have the buffer's shape \[2\]"):
        param.check_written_value(name, torch.zeros(3), "a table")
    with pytest.raises(ValueError, match=r"has no distribution buffer 'weight'"):
        param.check_written_value("weight", torch.zeros(2), "a table")
    with pytest.raises(TypeError, match="must be a tensor"):
        param.check_written_value(name, [0.0, 0.0], "a table")
    with pytest.raises(TypeError, match="bool"):
        param.check_written_value(name, torch.tensor([True, False]), "a table")


def test_a_row_may_go_into_any_env_the_whole_buffer_into_its_own_env():
    param = UniformDomainParam(NAME, 1.0, 0.0)
    param.use_per_env(torch.Size([2]))
    param.mean[1] = 10.0
    param.bind_field(MASS)
    param.check_written_value("halfspan", torch.tensor([0.5, 5.0], dtype=F64), "the whole buffer")
    with pytest.raises(ValueError, match=r"can write -4.0 into 'body_mass:torso'"):
        param.check_written_value("halfspan", torch.tensor(5.0), "a row")  # env 0 would reach 1 - 5
    with pytest.raises(ValueError, match=r"can write -4.0 into 'body_mass:torso'"):
        param.check_written_value("halfspan", torch.tensor([0.5, 0.5, 5.0]), "three rows")


FIELD_WRITES = [  # (kind's parameter bound to a field, buffer, value the field refuses, value it accepts)
    (lambda: UniformDomainParam(NAME, 3.5, 0.5), "halfspan", 3.5, 3.4),
    (lambda: UniformDomainParam(NAME, 3.5, 0.5), "mean", 0.5, 0.6),
    (lambda: NormalDomainParam(NAME, 3.5, 1.0, clip_lo=0.5), "clip_lo", 0.0, 0.01),
    (lambda: MultivariateNormalDomainParam(NAME, [3.5], [[1.0]], clip_lo=0.5), "clip_lo", -1.0, 0.2),
    (lambda: BernoulliDomainParam(NAME, 3.5, 4.0, 0.5), "val_0", -1.0, 1.0),
]


@pytest.mark.parametrize(("make", "buffer", "refused", "accepted"), FIELD_WRITES)
def test_check_written_value_refuses_a_support_leaving_the_bound_field(make, buffer, refused, accepted):
    param = make()
    mass = MASS if param.value_shape == () else MASS._replace(value_shape=torch.Size([1]))
    param.check_written_value(buffer, torch.tensor(refused).expand(param._buffers[buffer].shape), "unbound")
    param.bind_field(mass)
    value = torch.tensor(refused, dtype=F64).expand(param._buffers[buffer].shape)
    with pytest.raises(ValueError, match=r"a level table can write .* which it refuses: .* into 'body_mass:torso'"):
        param.check_written_value(buffer, value, "a level table")
    param.check_written_value(buffer, torch.tensor(accepted, dtype=F64).expand(value.shape), "a level table")


# ------------------------------------------------------------------------- checkpoints
@pytest.mark.parametrize("kind", KINDS)
def test_state_dict_round_trip_shared_and_per_env(kind):
    saved = build(kind, clip_lo=CLIPS[kind][0])
    saved.use_per_env(torch.Size([3]))
    write_rows(saved, ENV_ARGS[kind])
    fresh = build(kind)  # shared: takes the saved per-env shape
    assert fresh.load_state_dict(saved.state_dict()).missing_keys == []
    assert_same_state(fresh, saved.state_dict())
    assert torch.equal(fresh.sample(3, generator(4)), saved.sample(3, generator(4)))
    shared = build(kind, ENV_ARGS[kind][1])
    fresh.load_state_dict(shared.state_dict())  # and back
    assert_same_state(fresh, shared.state_dict())


def replaced(module: DomainParam, buffer: str, value, whole: bool = True) -> dict[str, torch.Tensor]:
    """The module's state with ``buffer`` replaced by ``value`` (``whole=False``: only the last env's row)."""
    saved = state(module)
    value = torch.as_tensor(value, dtype=F64)
    if whole:
        saved[buffer] = value
    else:
        saved[buffer].view(-1, *value.shape)[-1] = value
    return saved


LOAD_REFUSED = [  # (kind, buffer, saved value: one env's row, or the whole buffer with whole=True, message)
    ("uniform", "halfspan", [0.5, -1.0], False, "halfspan must be >= 0"),
    ("uniform", "mean", [math.nan, 0.0], False, "mean must not be NaN"),
    ("normal", "std", [-1.0, 1.0], False, "std must be >= 0"),
    ("mvn", "cov", [[1.0, 2.0], [2.0, 1.0]], False, "cov must be positive definite"),
    ("bernoulli", "prob_1", [0.5, 1.01], False, r"prob_1 must be in \[0, 1\]"),
    ("normal", "clip_lo", [5.0, 5.0], False, "clip_lo must not exceed clip_up"),
    ("uniform", "mean", [1.0, 2.0, 3.0], True, r"mean must have shape \[2\] or \[\*B, 2\]"),
    ("uniform", "halfspan", [[0.5, 0.5]] * 4, True, r"share their per-env leading dims"),
    ("mvn", "cov", [1.0, 1.0], True, r"cov must have shape \[2, 2\] or \[\*B, 2, 2\]"),
]


@pytest.mark.parametrize("per_env", [False, True], ids=["shared", "per_env"])
@pytest.mark.parametrize(("kind", "buffer", "value", "whole", "message"), LOAD_REFUSED)
def test_a_refused_load_leaves_the_module_unchanged(kind, buffer, value, whole, message, per_env):
    param = build(kind, clip_up=4.0)
    if per_env:
        param.use_per_env(torch.Size([3]))
    before = state(param)
    bad = replaced(param, buffer, value, whole)
    with pytest.raises(ValueError, match=message):
        param.load_state_dict(bad)
    assert_same_state(param, before)


def test_a_load_whose_draws_leave_the_bound_field_is_refused():
    param = UniformDomainParam(NAME, 3.5, 0.5)
    param.bind_field(MASS)
    before = state(param)
    with pytest.raises(ValueError, match=r"load_state_dict: .*can write 0.0 into 'body_mass:torso'"):
        param.load_state_dict(replaced(param, "halfspan", 3.5))
    assert_same_state(param, before)
    param.load_state_dict(replaced(param, "halfspan", 3.0))
    assert param.halfspan.item() == 3.0
