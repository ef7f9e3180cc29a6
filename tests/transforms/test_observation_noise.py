"""ObservationNoise on the torch pendulum: the noise's and the biases' moments against their definition, biases held per
episode and redrawn for the envs that reset, per-env stds drawn by a DomainRandomization (and scheduled), seeding,
checkpoints, refusals; and the DomainRandomization's routing of fields to their owners."""

from __future__ import annotations

import io
import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import Compose, SerialEnv, StepCounter, TransformedEnv, UnsqueezeTransform

from torchtasks.domain import UniformDomainParam
from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.stats import episode_statistics
from torchtasks.transforms import (
    Curriculum,
    DifficultyLevels,
    DomainRandomization,
    EntryNoise,
    ObservationNoise,
    TaskTransform,
    linear,
)
from walk_env import WalkEnv

NOISE = "observation_noise:observation"
BIAS = "observation_bias:observation"


def _vector(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


def _noise(**kwargs) -> ObservationNoise:
    """Noise on the pendulum's observation, written to "noisy" (the pendulum steps from the data's observation)."""
    return ObservationNoise({"observation": EntryNoise(out_key="noisy", **kwargs)}, seed=0)


def _env(*transforms, batch: int = 4, steps: int = 3) -> TransformedEnv:
    return TransformedEnv(PendulumEnv(batch_size=[batch], seed=0), Compose(StepCounter(steps), *transforms))


def _saved(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def _residuals(data: TensorDict) -> tuple[torch.Tensor, torch.Tensor]:
    """The offsets of the noisy copy from the clean entry at the reset and after every step (``[B, 1 + T, d]``), and
    the biases recorded with them (zeros for an entry without a bias)."""
    key = "observation_bias_observation"
    first, steps = data[:, :1], data["next"]
    offsets = torch.cat([first["noisy"] - first["observation"], steps["noisy"] - steps["observation"]], 1).double()
    if key not in first.keys(True):  # an entry without a bias
        return offsets, torch.zeros_like(offsets)
    return offsets, torch.cat([first[key], steps[key]], 1).double()


# ------------------------------------------------------------------------------------------------ moments
@pytest.mark.parametrize("distribution", ["normal", "uniform"])
def test_noise_and_bias_moments_over_many_envs(distribution: str):
    """Offset = bias + std * eps: the biases (one per env and element) have mean 0 and the given std; offset - bias has
    mean 0 and the given std, and a uniform draw stays within sqrt(3) * std (its half-width). Tolerances: 5 standard
    errors of each estimate (a variance's standard error from the distribution's fourth moment)."""
    std, bias_std = _vector(0.1, 0.3), _vector(0.2, 0.05)
    noise = _noise(std=std.float(), bias=bias_std.float(), distribution=distribution)
    env = _env(noise, batch=4096, steps=100)
    data = env.rollout(3)
    offsets, biases = _residuals(data)
    assert (biases == biases[:, :1]).all()  # one bias per episode
    kurtosis = 3.0 if distribution == "normal" else 1.8  # E[x^4] / std^4
    for sample, expected in ((biases[:, 0], bias_std), ((offsets - biases).reshape(-1, 2), std)):
        n = sample.shape[0]
        assert ((sample.mean(0) / expected).abs() < 5 / math.sqrt(n)).all()
        relative_variance = sample.var(0) / expected**2 - 1
        assert (relative_variance.abs() < 5 * math.sqrt((kurtosis - 1) / n)).all(), relative_variance
        if distribution == "uniform":
            assert (sample.abs() <= math.sqrt(3) * expected * (1 + 1e-6)).all()
            assert (sample.abs().amax(0) > 0.99 * math.sqrt(3) * expected).all()


def test_the_bias_is_held_per_episode_and_redrawn_for_the_envs_that_reset():
    env = _env(_noise(std=0.0, bias=1.0), steps=100)
    first = env.reset()
    bias = first["observation_bias_observation"]
    assert torch.equal(first["noisy"], first["observation"] + bias)  # std 0: the bias alone
    data = env.rollout(3, auto_reset=False, tensordict=first)
    assert (data["next", "observation_bias_observation"] == bias.unsqueeze(1)).all()
    last = data[:, -1]["next"].clone()
    reset = env.reset(last.set("_reset", torch.tensor([True, False, True, False]).reshape(4, 1)))
    redrawn = reset["observation_bias_observation"]
    assert torch.equal(redrawn[[1, 3]], bias[[1, 3]]) and (redrawn[[0, 2]] != bias[[0, 2]]).all()
    assert torch.equal(reset["noisy"][[1, 3]], last["noisy"][[1, 3]])  # the running episodes go on as they were
    assert torch.equal(reset["noisy"], reset["observation"].double().add(redrawn).float())
    assert torch.equal(redrawn, env.transform[1].bias.observation.float())


def test_entries_drawn_together_keep_their_own_moments_and_are_independent():
    """Several entries of one transform (one draw per distribution and dtype, each entry its columns): per entry and
    element, offset - bias has mean 0 and the entry's std and the bias its bias std; the noises of two entries drawn
    in one draw are uncorrelated (5 standard errors), a uniform entry stays within sqrt(3) * std, and an entry
    without a bias has no bias entry."""
    import mujoco  # noqa: F401  (the velocity-tracking env: several observation entries)

    from torchtasks.envs import velocity_tracking_env

    spec = {
        "lin_vel": EntryNoise(std=0.2, bias=0.1, out_key="noisy_lin_vel"),
        "joint_pos": EntryNoise(std=0.05, distribution="uniform", out_key="noisy_joint_pos"),
        "gravity": EntryNoise(std=0.1, bias=0.3, distribution="uniform", out_key="noisy_gravity"),
        "ang_vel": EntryNoise(std=0.4, bias=0.2, bias_distribution="uniform", out_key="noisy_ang_vel"),
    }
    env = velocity_tracking_env(2048, seed=0, perturbations=[ObservationNoise(spec, seed=0)])
    data = env.rollout(2, break_when_any_done=False)
    residuals = {}
    for key, entry in spec.items():
        noisy = torch.cat([data[entry.out_key], data["next", entry.out_key]], 1).double()
        clean = torch.cat([data[key], data["next", key]], 1).double()
        bias_key = f"observation_bias_{key}"
        if entry.bias is None:
            assert bias_key not in data.keys(True) and ("next", bias_key) not in data.keys(True)
            bias = torch.zeros_like(noisy)
        else:
            bias = torch.cat([data[bias_key], data["next", bias_key]], 1).double()
            assert (bias == bias[:, :1]).all()
            first = bias[:, 0]
            n = first.shape[0]
            assert (first.mean(0).abs() < 5 * entry.bias / math.sqrt(n)).all(), key
            assert ((first.var(0) / entry.bias**2 - 1).abs() < 5 * math.sqrt(2 / n)).all(), key
        residual = (noisy - clean - bias).reshape(-1, clean.shape[-1])
        n = residual.shape[0]
        kurtosis = 3.0 if entry.distribution == "normal" else 1.8
        assert (residual.mean(0).abs() < 5 * entry.std / math.sqrt(n)).all(), key
        relative = residual.var(0) / entry.std**2 - 1
        assert (relative.abs() < 5 * math.sqrt((kurtosis - 1) / n)).all(), (key, relative)
        if entry.distribution == "uniform":  # float32 entries: a relative slack for the rounding of the sum
            assert (residual.abs() <= math.sqrt(3) * entry.std * (1 + 1e-4) + 1e-5).all(), key
        residuals[key] = residual
    n = residuals["gravity"].shape[0]
    for a, b in (("joint_pos", "gravity"), ("lin_vel", "ang_vel"), ("lin_vel", "gravity")):
        x, y = residuals[a][:, 0], residuals[b][:, 0]
        correlation = float(((x - x.mean()) * (y - y.mean())).mean() / (x.std() * y.std()))
        assert abs(correlation) < 5 / math.sqrt(n), (a, b, correlation)
    env.close()


def test_an_entry_of_several_dimensions_gets_its_elements_stds():
    """A [B, 2, 1] entry drawn with a 1-D one in the same draw: each element has its own std and bias std."""
    std = torch.tensor([[0.1], [0.3]], dtype=torch.float64)
    bias = torch.tensor([[0.2], [0.05]], dtype=torch.float64)
    noise = ObservationNoise(
        {
            "observation": EntryNoise(std=0.05, out_key="noisy"),
            "column": EntryNoise(std=std.float(), bias=bias.float(), out_key="noisy_column"),
        },
        seed=0,
    )
    column = UnsqueezeTransform(dim=-1, in_keys=["observation"], out_keys=["column"])
    env = TransformedEnv(PendulumEnv(batch_size=[4096], seed=0), Compose(StepCounter(50), column, noise))
    data = env.rollout(3)
    assert data["next", "noisy_column"].shape == (4096, 3, 2, 1)
    offsets = (data["next", "noisy_column"] - data["next", "column"]).double()
    biases = data["next", "observation_bias_column"].double()
    residual = (offsets - biases).reshape(-1, 2)
    n = residual.shape[0]
    assert ((residual.var(0) / std.reshape(-1) ** 2 - 1).abs() < 5 * math.sqrt(2 / n)).all()
    first = biases[:, 0].reshape(-1, 2)
    assert ((first.var(0) / bias.reshape(-1) ** 2 - 1).abs() < 5 * math.sqrt(2 / first.shape[0])).all()
    other = (data["next", "noisy"] - data["next", "observation"]).double().reshape(-1, 2)
    assert ((other.var(0) / 0.05**2 - 1).abs() < 5 * math.sqrt(2 / other.shape[0])).all()


def test_an_entry_without_a_bias_has_no_bias_field_entry_or_draw():
    noise = _noise(std=0.1)
    env = _env(noise)
    data = env.rollout(2)
    assert "observation_bias_observation" not in data.keys(True)
    assert [field.name for field in noise.domain_fields()] == [NOISE]
    assert dict(noise.state_dict()).keys() == {"noise_std.observation", "_extra_state"}
    bias = DomainRandomization([UniformDomainParam(BIAS, mean=_vector(0.1, 0.1), halfspan=_vector(0.0, 0.0))])
    with pytest.raises(ValueError, match=r"has no per-episode bias \(EntryNoise\(bias=None\), the default\)"):
        _env(_noise(std=0.1), bias).reset()
    with pytest.raises(ValueError, match="bias_distribution of 'observation' is 'uniform' but it has no bias"):
        _noise(std=0.1, bias_distribution="uniform")


def test_the_bias_of_a_nested_entry_is_a_leaf_named_like_its_field_and_counted_by_the_statistics():
    """An entry ("sensors", "column") has its bias at "observation_bias_sensors:column" (a leaf beside the others,
    no node), given another prefix by entry_key; episode_statistics reads it by that prefix: the root mean square of
    the biases the ended episodes ended with, counted here frame by frame."""
    column = UnsqueezeTransform(dim=-1, in_keys=["observation"], out_keys=[("sensors", "column")])
    for entry_key, bias_key in [(None, "observation_bias_sensors:column"), ("imu_bias", "imu_bias_sensors:column")]:
        keywords = {} if entry_key is None else {"entry_key": entry_key}
        noise = ObservationNoise({("sensors", "column"): EntryNoise(bias=0.3, out_key="noisy")}, seed=0, **keywords)
        env = TransformedEnv(PendulumEnv(batch_size=[8], seed=0), Compose(StepCounter(4), column.clone(), noise))
        data = env.rollout(9, break_when_any_done=False)
        assert data["next", bias_key].shape == (8, 9, 2, 1)
        assert not isinstance(data.get("observation_bias", None), TensorDict)  # a leaf, no node
        ends = data["next", "done"].reshape(8, 9)
        squares = [
            float(v) ** 2 for row, t in ends.nonzero().tolist() for v in data["next", bias_key][row, t].flatten()
        ]
        keywords = {} if entry_key is None else {"bias_key": entry_key}
        stats = episode_statistics(data, **keywords)
        assert len(squares) == 8 * 2 * 2  # two ended episodes per env, two elements each
        assert math.isclose(stats["observation_bias_rms/sensors:column"], math.sqrt(sum(squares) / len(squares)))


def test_noise_in_place_replaces_the_entry():
    """In place, the reset's entry is what the copy would hold (the same seed draws the same numbers)."""
    copy = _env(_noise(std=0.1, bias=0.2)).reset()
    in_place = _env(ObservationNoise({"observation": EntryNoise(std=0.1, bias=0.2)}, seed=0)).reset()
    assert torch.equal(in_place["observation"], copy["noisy"])


# ------------------------------------------------------------------------------------------------ domain fields
def test_per_env_stds_drawn_by_a_randomization_are_the_noise_of_each_env():
    """The randomization draws each env's std (0.05 to 0.95) and bias std: the data's values are the noise's, and the
    offsets divided by each env's std are standard (their variance 1 within 5 standard errors; not so without)."""
    noise = _noise(bias=0.0)
    stds = UniformDomainParam(NOISE, mean=_vector(0.5, 0.5), halfspan=_vector(0.45, 0.45))
    biases = UniformDomainParam(BIAS, mean=_vector(0.0, 0.0), halfspan=_vector(0.0, 0.0))
    randomization = DomainRandomization([stds, biases], seed=1)
    env = _env(noise, randomization, batch=1024, steps=100)
    data = env.rollout(3)
    drawn = data["next", "domain", NOISE]
    assert torch.equal(drawn[:, -1], noise.noise_std.observation)
    assert (drawn == drawn[:, :1]).all() and drawn.std() > 0.2
    offsets, _ = _residuals(data)
    standard = offsets / torch.cat([drawn[:, :1], drawn], 1)
    n = standard.numel()
    assert abs(float(standard.var()) - 1) < 5 * math.sqrt(2 / n)
    assert abs(float((offsets / drawn.mean()).var()) - 1) > 10 * math.sqrt(2 / n)


def test_a_curriculum_widens_the_noise_over_frames():
    zero = _vector(0.0, 0.0)
    randomization = DomainRandomization([UniformDomainParam(NOISE, mean=zero, halfspan=zero)], seed=0)
    curriculum = Curriculum({f"domain.{NOISE}.mean": linear(0.0, 0.4, 0, 40)})
    env = _env(TaskTransform(swing_up_task()), _noise(), randomization, curriculum, batch=2)
    data = env.rollout(12, break_when_any_done=False)
    drawn = data["next", "domain", NOISE][..., 0]
    written = data["next", "curriculum", f"domain/{NOISE}/mean"][..., 0]
    starts = [3, 6, 9]  # the resets (StepCounter(3)) draw from the mean written at the step before
    assert torch.equal(drawn[:, starts], written[:, [t - 1 for t in starts]])
    assert drawn[0, 0] == 0.0 and drawn[0, -1] == pytest.approx(0.4 * 18 / 40)
    offsets, _ = _residuals(data)
    assert torch.equal(offsets[:, :4], torch.zeros_like(offsets[:, :4]))  # std 0 in the first episode
    assert episode_statistics(data)[f"domain/{NOISE}/0"] == pytest.approx((0.0 + 0.06 + 0.12 + 0.18) / 4)  # 4 ended


def test_levels_give_each_env_its_own_noise():
    zero = _vector(0.0, 0.0)
    randomization = DomainRandomization([UniformDomainParam(NOISE, mean=zero, halfspan=zero)], seed=0)
    levels = DifficultyLevels(2, {f"domain.{NOISE}.mean": [[0.0, 0.0], [0.5, 0.5]]}, initial_level=0)
    noise = _noise()
    env = _env(TaskTransform(swing_up_task()), noise, randomization, levels)
    env.reset()
    levels.level = torch.tensor([0, 1, 0, 1])
    data = env.rollout(6, break_when_any_done=False)
    offsets = data["next", "noisy"] - data["next", "observation"]
    assert (offsets[[0, 2]] == 0).all() and (offsets[[1, 3], 3:] != 0).all()  # level 1 from the reset at step 3
    assert (data["next", "domain", NOISE][[1, 3], 3:] == 0.5).all()


# ------------------------------------------------------------------------------------------------ routing
def test_a_randomization_draws_for_the_base_env_and_the_noise():
    randomization = DomainRandomization(
        [UniformDomainParam("mass", 1.0, 0.5), UniformDomainParam(NOISE, _vector(0.2, 0.2), _vector(0.1, 0.1))], seed=0
    )
    noise = _noise()
    env = _env(noise, randomization)
    reset = env.reset()
    assert torch.equal(env.base_env.domain_values(["mass"])["mass"], reset["domain", "mass"][:, 0])
    assert torch.equal(noise.noise_std.observation, reset["domain", NOISE])
    assert type(randomization._base_env()).__name__ == "DomainOwners"
    alone = DomainRandomization([UniformDomainParam("mass", 1.0, 0.5)])
    _env(alone).reset()
    assert isinstance(alone._base_env(), PendulumEnv)  # no owning transform: the base env itself, as before


def test_a_base_env_without_fields_takes_the_noise_fields_alone():
    """WalkEnv owns no domain fields: the noise owns every drawn one, and a physics name is unknown."""
    randomization = DomainRandomization([UniformDomainParam(NOISE, _vector(0.2), _vector(0.1))], seed=0)
    env = TransformedEnv(WalkEnv([2]), Compose(_noise(), randomization))
    assert env.reset()["domain", NOISE].shape == (2, 1)
    mass = DomainRandomization([UniformDomainParam("mass", 1.0, 0.5)])
    with pytest.raises(ValueError, match=r"unknown domain field 'mass'.* in this env: ObservationNoise \(1 field\)"):
        TransformedEnv(WalkEnv([2]), Compose(_noise(), mass)).reset()
    with pytest.raises(TypeError, match="got WalkEnv, and no transform before the DomainRandomization owns"):
        TransformedEnv(WalkEnv([2]), Compose(DomainRandomization([UniformDomainParam("mass", 1.0, 0.5)]))).reset()


@pytest.mark.parametrize(
    ("name", "match"),
    [
        (
            "observation_noise:obs",
            r"unknown domain field 'observation_noise:obs' in names; did you mean "
            r"'observation_noise:observation'.*the base env PendulumEnv \(3 fields\), ObservationNoise \(1 field\)",
        ),
        ("mas", r"unknown domain field 'mas' in names; did you mean 'mass'"),
    ],
)
def test_an_unknown_field_lists_the_close_names_of_all_owners(name: str, match: str):
    randomization = DomainRandomization([UniformDomainParam(name, 1.0, 0.5)])
    with pytest.raises(ValueError, match=match):
        _env(_noise(), randomization).reset()


def test_a_field_offered_by_two_owners_and_an_owner_after_the_randomization_are_refused():
    twice = DomainRandomization([UniformDomainParam("mass", 1.0, 0.5)])
    with pytest.raises(ValueError, match=f"'{NOISE}' is offered by ObservationNoise and by ObservationNoise"):
        _env(_noise(), ObservationNoise({"observation": EntryNoise(out_key="other")}), twice).reset()
    after = DomainRandomization([UniformDomainParam("mass", 1.0, 0.5)])
    with pytest.raises(ValueError, match="ObservationNoise, which owns domain fields, comes after it"):
        _env(after, _noise()).reset()


# ------------------------------------------------------------------------------------------------ run state
def test_set_seed_gives_each_worker_its_own_stream_and_repeats():
    def make_env() -> TransformedEnv:
        return _env(_noise(std=0.1, bias=0.1), batch=2)

    def noisy(seed: int) -> torch.Tensor:
        env = SerialEnv(2, make_env)
        env.set_seed(seed)
        torch.manual_seed(0)  # the same random actions
        offsets = env.rollout(2)
        env.close()
        return offsets["next", "noisy"] - offsets["next", "observation"]

    first = noisy(3)
    assert not torch.equal(first[0], first[1])
    assert torch.equal(noisy(3), first) and not torch.equal(noisy(4), first)


def test_a_checkpoint_resumes_bit_for_bit():
    """Save after 4 steps (an episode ended), continue; a fresh env loads it and continues: the same data."""

    def make_env() -> TransformedEnv:
        stds = UniformDomainParam(NOISE, _vector(0.2, 0.2), _vector(0.1, 0.1))
        return _env(_noise(std=0.1, bias=0.3, distribution="uniform"), DomainRandomization([stds], seed=2), steps=3)

    def run(env: TransformedEnv, carried: TensorDict, steps: int) -> tuple[list[TensorDict], TensorDict]:
        frames = []
        for _ in range(steps):  # a collector's loop
            frame, carried = env.step_and_maybe_reset(carried.set("action", torch.full((4, 1), 0.5)))
            frames.append(frame)
        return frames, carried

    env = make_env()
    _, carried = run(env, env.reset(), 4)
    state = _saved({"transforms": env.state_dict(), "base": env.base_env.state_dict()})
    expected, _ = run(env, carried.clone(), 5)
    fresh = make_env()
    fresh.load_state_dict(state["transforms"])
    fresh.base_env.load_state_dict(state["base"])
    resumed, _ = run(fresh, carried.clone(), 5)
    assert all((a == b).all() for a, b in zip(resumed, expected, strict=True))
    assert not torch.equal(expected[0]["next", "noisy"], expected[1]["next", "noisy"])


def test_a_checkpoint_of_another_noise_is_refused_and_changes_nothing():
    env = _env(_noise(std=0.1, bias=0.3))
    env.rollout(2)
    other = _env(_noise(std=0.1, bias=0.3, distribution="uniform"))
    other.rollout(2)
    before = {key: value.clone() for key, value in other.state_dict().items() if isinstance(value, torch.Tensor)}
    with pytest.raises(ValueError, match="checkpoint is of another noise"):
        other.load_state_dict(_saved(env.state_dict()))
    smaller = _env(_noise(std=0.1, bias=0.3), batch=3)
    smaller.rollout(2)
    with pytest.raises(ValueError, match=r"holds values of 'observation' of shape \[4, 2\].*this env gives \[3, 2\]"):
        smaller.load_state_dict(_saved(env.state_dict()))
    after = other.state_dict()
    assert all(torch.equal(after[key], value) for key, value in before.items())


# ------------------------------------------------------------------------------------------------ refusals
@pytest.mark.parametrize(
    ("noise", "error", "match"),
    [
        (
            EntryNoise(std=-0.1),
            ValueError,
            r"the std of 'observation' is a standard deviation .* >= 0",
        ),
        (EntryNoise(bias=torch.tensor([0.1, math.nan])), ValueError, r"the bias of 'observation' .* finite and >= 0"),
        (EntryNoise(distribution="laplace"), ValueError, r"distribution of 'observation' must be one of"),
        (EntryNoise(std=torch.tensor([1, 2])), TypeError, "float tensor"),
        ({"std": 0.1}, TypeError, r"must be an EntryNoise"),
    ],
)
def test_bad_noise_is_refused_at_construction(noise, error: type, match: str):
    with pytest.raises(error, match=match):
        ObservationNoise({"observation": noise})


def test_a_bias_entry_that_is_an_out_key_is_refused_at_construction():
    with pytest.raises(ValueError, match="bias entry 'noisy_observation' of 'observation' is an out_key"):
        ObservationNoise({"observation": EntryNoise(bias=0.1, out_key="noisy_observation")}, entry_key="noisy")


@pytest.mark.parametrize(
    ("noises", "transforms", "error", "match"),
    [
        (
            {"obs": EntryNoise()},
            [],
            ValueError,
            r"no observation entry 'obs' in the env; the entries are \['observation', 'step_count'\]",
        ),
        (
            {"observation": EntryNoise(std=torch.ones(3))},
            [],
            ValueError,
            r"std of 'observation' must be a number .* "
            r"per-env shape \[2\], got shape \[3\]",
        ),
        (
            {"observation": EntryNoise()},
            [TaskTransform(swing_up_task())],
            ValueError,
            r"reads 'observation' as its state.*"
            r"keeps judging the true state. Give the task its own state entry",
        ),
        ({"observation": EntryNoise(out_key="step_count")}, [], ValueError, "out_key 'step_count' .* already names"),
        ({"step_count": EntryNoise()}, [], TypeError, "dtype torch.int64"),
        (
            {"observation": EntryNoise(bias=0.1, out_key="noisy")},
            [UnsqueezeTransform(dim=-1, in_keys=["observation"], out_keys=["observation_bias_observation"])],
            ValueError,
            "the bias entry 'observation_bias_observation' of 'observation' already names an entry",
        ),
    ],
)
def test_bad_entries_are_refused_when_the_env_is_built(noises, transforms, error: type, match: str):
    env = _env(*transforms, ObservationNoise(noises))
    with pytest.raises(error, match=match):
        env.reset()


def test_the_data_keeps_its_biases_when_the_transform_is_loaded() -> None:
    """The bias entries handed to the data are never written into: a load into the transform (which copies into its
    buffers in place) leaves the data collected before it as it was."""

    def make(seed: int) -> TransformedEnv:
        noise = ObservationNoise({"observation": EntryNoise(std=0.1, bias=0.5, out_key="noisy")}, seed=seed)
        return TransformedEnv(
            PendulumEnv(batch_size=[4], seed=seed, dtype=torch.float64),  # float64: the cast is the buffer's dtype
            Compose(StepCounter(5), TaskTransform(swing_up_task()), noise),
        )

    env, other = make(0), make(1)
    data = env.reset()
    other.reset()
    bias = data["observation_bias_observation"]
    kept = bias.clone()
    env.transform[-1].load_state_dict(other.transform[-1].state_dict())
    assert not torch.equal(env.transform[-1].bias._buffers["observation"].to(kept.dtype), kept)  # the load changed it
    assert torch.equal(bias, kept)
