"""DomainRandomization on the torch pendulum: when values are drawn, that the physics use them, the stored domains,
seeding, checkpoints and refusals. (The invariant suite runs the two domain features through every data layout,
worker processes and resumes; the MuJoCo fields are held to per-env MjModel copies in the env tests.)"""

from __future__ import annotations

import io

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import Compose, SerialEnv, StepCounter, TransformedEnv

from feature_envs import pendulum_policy
from torchtasks.domain import BernoulliDomainParam, NormalDomainParam, UniformDomainParam
from torchtasks.envs import PendulumEnv, PointMassEnv, pendulum_dynamics, swing_up_task
from torchtasks.transforms import (
    BaseEnvState,
    Curriculum,
    DifficultyLevels,
    DomainRandomization,
    TaskTransform,
    collector_state,
    linear,
    load_collector_state,
)

BATCH = 4


def _env(randomization: DomainRandomization, *, batch: int = BATCH, steps: int = 5, seed: int = 0) -> TransformedEnv:
    return TransformedEnv(PendulumEnv(batch_size=[batch], seed=seed), Compose(StepCounter(steps), randomization))


def _mass(**kwargs) -> DomainRandomization:
    return DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.5)], seed=0, **kwargs)


def _saved(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def _partial_reset(env: TransformedEnv, last: TensorDict, mask: list[bool]) -> TensorDict:
    """Reset the envs of ``mask`` (TorchRL's ``"_reset"``) after ``last``, the last reset's output."""
    return env.reset(last.clone().set("_reset", torch.tensor(mask).reshape(BATCH, 1)))


# ------------------------------------------------------------------------------------------------ the physics
@pytest.mark.parametrize("when", ["reset", "interval"])
def test_the_physics_use_the_drawn_values(when: str):
    """Every step's physics are the values under "next" (interval: drawn before the step they apply to)."""
    params = [
        UniformDomainParam("mass", mean=1.0, halfspan=0.5),
        NormalDomainParam("length", mean=1.0, std=0.2, clip_lo=0.5),
        BernoulliDomainParam("gravity", val_0=5.0, val_1=15.0, prob_1=0.5),
    ]
    kwargs = {"when": "interval", "every": 3} if when == "interval" else {}
    env = _env(DomainRandomization(params, seed=1, **kwargs))
    data = env.rollout(12, break_when_any_done=False)
    for t in range(12):
        values = {name: data["next", "domain", name][:, t, 0].float() for name in ("mass", "length", "gravity")}
        expected = pendulum_dynamics(
            data["observation"][:, t], data["action"][:, t].clamp(-2.0, 2.0), dt=0.05, max_speed=8.0, **values
        )
        assert torch.equal(data["next", "observation"][:, t], expected), f"step {t}"
    masses = data["next", "domain", "mass"]
    assert not torch.equal(masses[:, 0], masses[:, 5])  # redrawn at the reset after 5 steps (interval: after 3)


# ------------------------------------------------------------------------------------------------ when
def test_reset_draws_for_the_reset_envs_only():
    env = _env(_mass())
    last = env.reset()
    before = last["domain", "mass"][:, 0]
    after = _partial_reset(env, last, [True, False, True, False])["domain", "mass"][:, 0]
    assert torch.equal(after[[1, 3]], before[[1, 3]])
    assert (after[[0, 2]] != before[[0, 2]]).all()
    assert torch.equal(env.base_env.domain_values(["mass"])["mass"], after)


def test_startup_draws_once_per_env():
    env = _env(_mass(when="startup"))
    first = env.reset()["domain", "mass"]
    data = env.rollout(12, break_when_any_done=False)  # two more resets
    assert (data["next", "domain", "mass"] == first.unsqueeze(1)).all()
    assert torch.equal(env.reset()["domain", "mass"], first)


def test_interval_draws_every_n_steps_of_each_env_across_episodes():
    env = _env(_mass(when="interval", every=4), steps=3)
    data = env.rollout(12, break_when_any_done=False)
    masses = torch.cat([data["domain", "mass"][:, :1], data["next", "domain", "mass"]], dim=1)[..., 0]  # 13 per env
    changed = (masses[:, 1:] != masses[:, :-1]).all(0)
    # drawn before steps 5 and 9 (1-based; after 4 steps each), never at the resets after steps 3, 6, 9: a step's
    # entries under "next" are the values it ran with
    assert changed.tolist() == [t in (4, 8) for t in range(12)]


def test_a_cycle_gives_the_stored_domains_in_turn():
    sets = {"mass": torch.tensor([0.5, 1.0, 1.5], dtype=torch.float64)}
    env = _env(DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.5)], cycle=sets))
    assert env.reset()["domain", "mass"][:, 0].tolist() == [0.5, 1.0, 1.5, 0.5]
    last = env.reset()
    assert last["domain", "mass"][:, 0].tolist() == [1.0, 1.5, 0.5, 1.0]
    partial = _partial_reset(env, last, [False, True, False, True])
    assert partial["domain", "mass"][:, 0].tolist() == [1.0, 1.5, 0.5, 0.5]


def test_a_drawn_cycle_is_drawn_once_and_reused():
    randomization = _mass(cycle=2)
    env = _env(randomization)
    first = env.reset()["domain", "mass"][:, 0]
    stored = randomization.domains.mass.clone()
    assert first.tolist() == [stored[0].item(), stored[1].item()] * 2
    env.rollout(20, break_when_any_done=False)
    assert torch.equal(randomization.domains.mass, stored)
    assert set(env.reset()["domain", "mass"][:, 0].tolist()) <= set(stored.tolist())


# ------------------------------------------------------------------------------------------------ seeding
def test_seeded_runs_repeat_and_workers_differ():
    def make() -> TransformedEnv:
        return _env(_mass())

    runs = []
    for _ in range(2):
        env = SerialEnv(2, make)
        env.set_seed(7)
        runs.append(env.rollout(11, break_when_any_done=False)["next", "domain", "mass"])
        env.close()
    assert torch.equal(runs[0], runs[1])
    assert not torch.equal(runs[0][0], runs[0][1])  # each worker its own stream
    other = SerialEnv(2, make)
    other.set_seed(8)
    assert not torch.equal(other.rollout(11, break_when_any_done=False)["next", "domain", "mass"], runs[0])
    other.close()


# ------------------------------------------------------------------------------------------------ checkpoints
def _resumable(randomization: DomainRandomization) -> TransformedEnv:
    env = PendulumEnv(batch_size=[BATCH], seed=0)
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    return TransformedEnv(env, Compose(StepCounter(5), task, randomization, BaseEnvState()))


MODES = {
    "reset": lambda: _mass(),
    "startup": lambda: _mass(when="startup"),
    "interval": lambda: _mass(when="interval", every=3),
    "cycle": lambda: _mass(cycle=3),
}


@pytest.mark.parametrize("mode", list(MODES))
def test_save_then_load_continues_the_run(mode: str):
    def collector() -> Collector:
        env, policy = _resumable(MODES[mode]()), pendulum_policy()
        return Collector(
            env, policy, frames_per_batch=BATCH * 7, total_frames=-1, auto_register_policy_transforms=False
        )

    running = collector()
    running.set_seed(3)
    batches = iter(running)
    next(batches)
    checkpoint = _saved(collector_state(running))
    expected = [next(batches).clone() for _ in range(2)]
    running.shutdown()
    resumed = collector()
    load_collector_state(resumed, checkpoint)
    batches = iter(resumed)
    actual = [next(batches).clone() for _ in range(2)]
    resumed.shutdown()
    for first, second in zip(expected, actual, strict=True):
        for key in (("next", "domain", "mass"), ("next", "observation"), "action"):
            assert torch.equal(first[key], second[key]), key


def test_a_loaded_state_is_given_to_the_env_at_once():
    source = _env(_mass())
    source.rollout(7, break_when_any_done=False)
    state = _saved(source.transform.state_dict())
    target = _env(_mass())
    target.reset()
    target.transform.load_state_dict(state)
    assert torch.equal(target.base_env.domain_values(["mass"])["mass"], source.base_env.domain_values(["mass"])["mass"])


@pytest.mark.parametrize(
    ("other", "match"),
    [
        (lambda: _mass(when="startup"), "when: saved 'reset', here 'startup'"),
        (lambda: _mass(cycle=3), "cycle: saved None, here 3"),
        (
            lambda: DomainRandomization([NormalDomainParam("mass", mean=1.0, std=0.1, clip_lo=0.5)], seed=0),
            "NormalDomainParam",
        ),
        (lambda: DomainRandomization([UniformDomainParam("length", mean=1.0, halfspan=0.5)], seed=0), "'length'"),
        (
            lambda: DomainRandomization(
                [UniformDomainParam("mass", mean=1.0, halfspan=0.5, clip_lo=0.6, roundint=True)], seed=0
            ),
            r"saved \{'mass': \['UniformDomainParam', False\]\}",
        ),
        (lambda: _mass(), "the saved distribution of 'mass'"),  # the same configuration, a negative halfspan saved
    ],
)
def test_a_load_of_another_randomization_is_refused_and_changes_nothing(other, match: str):
    source = _env(_mass())
    source.rollout(7, break_when_any_done=False)
    state = _saved(source.transform.state_dict())
    if match == "the saved distribution of 'mass'":
        state["transforms.1.params.mass.halfspan"] = torch.tensor(-1.0, dtype=torch.float64)
    target = _env(other())
    target.reset()
    before = _saved(target.transform.state_dict())
    with pytest.raises(ValueError, match=match):
        target.transform.load_state_dict(state)
    after = target.transform.state_dict()
    assert before.keys() == after.keys()
    for key, value in before.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, after[key]), key


def test_a_state_loaded_before_the_env_is_built_reaches_the_env():
    source = _env(_mass(when="startup"))
    source.reset()
    state = _saved(source.transform.state_dict())
    loaded = _mass(when="startup")
    loaded.load_state_dict(_saved({key.removeprefix("transforms.1."): v for key, v in state.items() if "1." in key}))
    env = _env(loaded)
    masses = env.reset()["domain", "mass"][:, 0]
    assert torch.equal(masses, source.base_env.domain_values(["mass"])["mass"])
    assert torch.equal(env.base_env.domain_values(["mass"])["mass"], masses)  # the env runs what the data says
    other = _mass(when="startup")
    other.load_state_dict(_saved({key.removeprefix("transforms.1."): v for key, v in state.items() if "1." in key}))
    with pytest.raises(ValueError, match=r"holds the drawn values of a batch \[4\].*the env's batch is \[6\]"):
        _env(other, batch=6).reset()


def test_an_unbatched_env_is_randomized():
    env = TransformedEnv(PendulumEnv(seed=0), Compose(StepCounter(3), _mass()))
    data = env.rollout(7, break_when_any_done=False)
    masses = data["next", "domain", "mass"]
    assert masses.shape == (7, 1) and masses[0] != masses[3]  # redrawn at the reset after 3 steps


def test_a_load_of_values_outside_the_field_is_refused():
    source = _env(_mass())
    source.reset()
    state = _saved(source.transform.state_dict())
    state["transforms.1.drawn.mass"] = torch.full((BATCH,), -1.0, dtype=torch.float64)
    target = _env(_mass())
    target.reset()
    with pytest.raises(ValueError, match="leave its range"):
        target.transform.load_state_dict(state)


# ------------------------------------------------------------------------------------------------ refusals
def test_an_unknown_field_names_the_fields():
    env = _env(DomainRandomization([UniformDomainParam("mas", mean=1.0, halfspan=0.5)]))
    with pytest.raises(ValueError, match="unknown domain field 'mas' in names; did you mean 'mass'"):
        env.reset()


def test_a_base_env_without_per_env_physics_is_refused():
    env = TransformedEnv(PointMassEnv(batch_size=[2]), _mass())
    with pytest.raises(TypeError, match=r"must offer per-env physics .* got PointMassEnv"):
        env.reset()


def test_two_randomizations_of_one_field_are_refused():
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(_mass(), _mass()))
    with pytest.raises(ValueError, match="also draws \\['mass'\\]"):
        env.reset()


def test_a_distribution_that_can_leave_the_field_is_refused():
    wide = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=1.0)])
    with pytest.raises(ValueError, match=r"can write 0\.0 into 'mass'"):
        _env(wide).reset()
    unbounded = DomainRandomization([NormalDomainParam("length", mean=1.0, std=0.1)])
    with pytest.raises(ValueError, match="'length'"):
        _env(unbounded).reset()


def test_a_schedule_that_would_widen_past_the_field_is_refused():
    task = TaskTransform(swing_up_task())
    curriculum = Curriculum({"domain.mass.halfspan": linear(0.0, 1.5, 0, 100)})
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(task, _mass(), curriculum))
    with pytest.raises(ValueError, match=r"Curriculum: the schedule of .domain\.mass\.halfspan."):
        env.reset()


@pytest.mark.parametrize(
    ("rows", "match"),
    [
        ([0.0, 0.25, 1.0], r"level 2 of 'domain\.mass\.halfspan'.*'mass'"),  # a mass range reaching 0
        ([0.0, -0.25, 0.5], r"level 1 of 'domain\.mass\.halfspan'.*halfspan"),  # a negative halfspan
    ],
)
def test_a_level_table_that_leaves_the_field_or_the_distribution_is_refused(rows: list[float], match: str):
    task = TaskTransform(swing_up_task())
    levels = DifficultyLevels(3, {"domain.mass.halfspan": rows})
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(task, _mass(), levels))
    with pytest.raises(ValueError, match=match):
        env.reset()


def test_per_env_levels_draw_from_each_envs_distribution():
    task = TaskTransform(swing_up_task())
    levels = DifficultyLevels(3, {"domain.mass.halfspan": [0.0, 0.25, 0.5]}, initial_level=0)
    randomization = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.0)], seed=0)
    env = TransformedEnv(PendulumEnv(batch_size=[BATCH]), Compose(StepCounter(5), task, randomization, levels))
    env.reset()
    levels.level = torch.tensor([0, 2, 0, 2])  # envs 1 and 3 at the widest level
    masses = env.rollout(40, break_when_any_done=False)["next", "domain", "mass"]
    assert (masses[[0, 2]] == 1.0).all()  # halfspan 0: the nominal mass
    assert (masses[[1, 3]] != 1.0).any() and ((masses - 1.0).abs() <= 0.5).all()
    assert randomization.params["mass"].halfspan.shape == (BATCH,)


def test_a_curriculum_before_the_randomization_is_refused():
    task = TaskTransform(swing_up_task())
    curriculum = Curriculum({"domain.mass.halfspan": linear(0.0, 0.5, 0, 100)})
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(task, curriculum, _mass()))
    with pytest.raises(ValueError, match="DomainRandomization that comes after it: put Curriculum after it"):
        env.reset()


@pytest.mark.parametrize("writer", ["curriculum", "levels"])
def test_the_first_reset_draws_from_the_written_distribution(writer: str):
    """TorchRL runs the pre-reset hooks last to first: the writer after the randomization writes first."""
    task = TaskTransform(swing_up_task())
    if writer == "curriculum":
        written = Curriculum({"domain.mass.halfspan": linear(0.0, 0.5, 1000, 2000)})  # 0 until frame 1000
    else:
        written = DifficultyLevels(2, {"domain.mass.halfspan": [0.0, 0.5]})  # level 0: the nominal mass
    env = TransformedEnv(PendulumEnv(batch_size=[BATCH]), Compose(task, _mass(), written))
    assert (env.reset()["domain", "mass"] == 1.0).all()


def test_two_written_parameters_are_checked_together():
    """Each schedule (level table) alone keeps the mass above 0; the mean and the halfspan together do not."""

    def env(writer) -> TransformedEnv:
        narrow = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.0)])
        return TransformedEnv(PendulumEnv(batch_size=[2]), Compose(TaskTransform(swing_up_task()), narrow, writer))

    schedules = {"domain.mass.mean": linear(1.0, 0.5, 0, 100), "domain.mass.halfspan": linear(0.0, 0.9, 0, 100)}
    with pytest.raises(ValueError, match=r"Curriculum: the schedules of .* together .* can write -0\.\d+ into 'mass'"):
        env(Curriculum(schedules)).reset()
    tables = {"domain.mass.mean": [1.0, 0.5], "domain.mass.halfspan": [0.0, 0.9]}
    level = r"DifficultyLevels: level 1 of 'domain\.mass\.mean' and 'domain\.mass\.halfspan' can write"
    with pytest.raises(ValueError, match=level + r" .* together .* into 'mass'"):
        env(DifficultyLevels(2, tables)).reset()
    env(Curriculum({"domain.mass.mean": linear(1.0, 0.5, 0, 100)})).reset()  # alone: accepted
    env(Curriculum({"domain.mass.halfspan": linear(0.0, 0.9, 0, 100)})).reset()


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"when": "episode"}, ValueError, "when must be one of"),
        ({"when": "interval"}, ValueError, "every .* is required with when='interval'"),
        ({"every": 3}, ValueError, "refused otherwise"),
        ({"cycle": 0}, ValueError, "cycle"),
        ({"cycle": {"length": torch.ones(2, dtype=torch.float64)}}, ValueError, "exactly the params' fields"),
        ({"cycle": {"mass": torch.ones(2)}}, TypeError, "float64"),
        ({"cycle": {"mass": torch.ones(2, 1, dtype=torch.float64)}}, ValueError, r"shape \[K"),
    ],
)
def test_bad_arguments_are_refused(kwargs: dict, error: type, match: str):
    with pytest.raises(error, match=match):
        DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.5)], **kwargs)


def test_params_must_be_domain_params_with_distinct_fields():
    with pytest.raises(TypeError, match="params\\[0\\] must be a DomainParam"):
        DomainRandomization([1.0])
    twice = [UniformDomainParam("mass", mean=1.0, halfspan=0.1), UniformDomainParam("mass", mean=1.0, halfspan=0.2)]
    with pytest.raises(ValueError, match="distinct domain fields"):
        DomainRandomization(twice)
