"""Writers of domain distributions: every writer (a Curriculum of every schedule kind, DifficultyLevels) x every
randomization mode x every kind of domain distribution is honoured (the env's drawn physics follow the written
values) or refused when the specs are built; the writers of one distribution are checked together, at every
combination of their values; a draw the env refuses changes nothing."""

from __future__ import annotations

import copy
import functools
import re
from collections.abc import Callable
from dataclasses import dataclass

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.domain import (
    BernoulliDomainParam,
    DomainParam,
    MultivariateNormalDomainParam,
    NormalDomainParam,
    UniformDomainParam,
)
from torchtasks.envs import PendulumEnv, gymnasium_env, swing_up_task
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import DesiredStateTask
from torchtasks.transforms import (
    Curriculum,
    DifficultyLevels,
    DomainRandomization,
    TaskTransform,
    constant,
    gated,
    linear,
    staged,
    target_names,
)

BATCH = 4
EPISODE = 3  # steps per episode: resets (and so draws, level moves and gated stages) come often
NARROW = 1e-4  # the largest distance from the nominal value of a draw from the narrow distribution
WIDE = 1e-2  # some draw of the wide distribution is farther than this from it


# ------------------------------------------------------------------------------------------------ the table
@dataclass(frozen=True)
class Kind:
    """A kind of domain distribution, with a parameter that sets its spread: ``narrow`` draws the nominal value."""

    param: Callable[[torch.Tensor], DomainParam]
    buffer: str
    narrow: torch.Tensor
    wide: torch.Tensor
    mujoco: bool = False  # a vector field: drawn for a batched MuJoCo env's gravity

    @functools.cached_property
    def field(self) -> str:
        return self.param(self.narrow).name

    @property
    def target(self) -> str:
        return f"domain.{self.field}.{self.buffer}"

    @functools.cached_property
    def nominal(self) -> torch.Tensor:
        return self.param(self.narrow).sample(1, torch.Generator().manual_seed(0))[0]


def _scalar(value: float) -> torch.Tensor:
    return torch.tensor(value, dtype=torch.float64)


def _eye(scale: float) -> torch.Tensor:
    return torch.eye(3, dtype=torch.float64) * scale


KINDS = {
    "uniform": Kind(lambda s: UniformDomainParam("mass", mean=1.0, halfspan=s), "halfspan", _scalar(0.0), _scalar(0.5)),
    "normal": Kind(
        lambda s: NormalDomainParam("length", mean=1.0, std=s, clip_lo=0.5, clip_up=1.5),
        "std",
        _scalar(0.0),
        _scalar(0.2),
    ),
    "bernoulli": Kind(
        lambda s: BernoulliDomainParam("gravity", val_0=10.0, val_1=5.0, prob_1=s), "prob_1", _scalar(0.0), _scalar(0.5)
    ),
    "multivariate_normal": Kind(
        lambda s: MultivariateNormalDomainParam("gravity", [0.0, 0.0, -9.81], s, clip_lo=-20.0, clip_up=20.0),
        "cov",
        _eye(1e-12),  # positive definite: the narrowest covariance there is
        _eye(0.25),
        mujoco=True,
    ),
}


def _up(tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> torch.Tensor:
    """A level up at every episode end."""
    return torch.ones(next_tensordict.batch_size, dtype=torch.int64)


# every writer kind: (writer of narrow then wide, whether the first draw is narrow). Frames grow by BATCH a step; the
# first episode ends at step EPISODE: the gated stage and the levels move then.
WRITERS = {
    "constant": (lambda target, narrow, wide: Curriculum({target: constant(wide)}), False),
    "linear": (lambda target, narrow, wide: Curriculum({target: linear(narrow, wide, 2 * BATCH, 4 * BATCH)}), True),
    "staged": (lambda target, narrow, wide: Curriculum({target: staged({0: narrow, 3 * BATCH: wide})}), True),
    "gated": (
        lambda target, narrow, wide: Curriculum({target: gated([narrow, wide], "step_count", threshold=0.0, window=1)}),
        True,
    ),
    "levels": (lambda target, narrow, wide: DifficultyLevels(2, {target: torch.stack([narrow, wide])}, rule=_up), True),
}


def _given(kind: Kind) -> dict[str, torch.Tensor]:
    return {kind.field: kind.nominal.expand(3, *kind.nominal.shape).clone()}


# every moment x cycle: (DomainRandomization kwargs, the words of the refusal; None: honoured)
MODES = {
    "reset": (lambda kind: {}, None),
    "interval": (lambda kind: {"when": "interval", "every": 2}, None),
    "startup": (lambda kind: {"when": "startup"}, "when='startup'"),
    **{
        f"{when}, cycle=3": (lambda kind, extra=extra: {**extra, "cycle": 3}, "cycle=3")
        for when, extra in (
            ("reset", {}),
            ("interval", {"when": "interval", "every": 2}),
            ("startup", {"when": "startup"}),
        )
    },
    **{
        f"{when}, given cycle": (lambda kind, extra=extra: {**extra, "cycle": _given(kind)}, "cycle={...}")
        for when, extra in (
            ("reset", {}),
            ("interval", {"when": "interval", "every": 2}),
            ("startup", {"when": "startup"}),
        )
    },
}


def _base(kind: Kind) -> TransformedEnv:
    """An env with a task and short episodes, for the randomization and the writer to be appended."""
    if kind.mujoco:
        return _hopper()
    task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [1e-3]))  # few entries
    return TransformedEnv(PendulumEnv(batch_size=[BATCH], seed=0), Compose(StepCounter(EPISODE), TaskTransform(task)))


def _hopper() -> TransformedEnv:
    """The batched Hopper preset's env and task, with short episodes."""
    preset = gymnasium_env("Hopper-v5", num_envs=BATCH, seed=0, backend="batched")
    task = preset.transform[1]
    return TransformedEnv(
        preset.base_env, Compose(StepCounter(EPISODE), TaskTransform(task.task, state_key=list(task.state_keys)))
    )


@pytest.fixture(scope="module")
def bases() -> dict[str, tuple[TransformedEnv, int]]:
    """One env per kind of distribution, shared by the cells (each cell appends its own randomization and writer to
    it, in place of the last cell's: building an env costs more than a cell's checks)."""
    return {name: (env, len(env.transform)) for name, env in ((name, _base(kind)) for name, kind in KINDS.items())}


def _env(bases: dict, name: str, mode: str, writer: str) -> TransformedEnv:
    kind = KINDS[name]
    env, length = bases[name]
    while len(env.transform) > length:
        env.transform.pop()
    env.append_transform(DomainRandomization([kind.param(kind.narrow)], seed=0, **MODES[mode][0](kind)))
    env.append_transform(WRITERS[writer][0](kind.target, kind.narrow, kind.wide))
    return env


def _distance(values: torch.Tensor, nominal: torch.Tensor) -> torch.Tensor:
    """Every env's largest distance from the nominal value, ``[*B]``."""
    return (values - nominal).abs().reshape(*values.shape[: values.dim() - nominal.dim()], -1).amax(-1)


def _entry(values: torch.Tensor, kind: Kind) -> torch.Tensor:
    """The env's values ``[*B, *value_shape]`` as the data hold them: a scalar field's ``[*B, 1]``."""
    return values.unsqueeze(-1) if kind.nominal.dim() == 0 else values


def _check_honoured(env: TransformedEnv, kind: Kind, writer: str, case: str) -> None:
    """The env's values are nominal while the written spread is 0 and spread once the writer widens it, always inside
    the widest distribution's range; the data report them and the written value."""
    reset = env.reset()
    first = env.base_env.domain_values([kind.field])[kind.field]
    assert torch.equal(reset["domain", kind.field], _entry(first, kind)), case
    if WRITERS[writer][1]:
        assert (_distance(first, kind.nominal) <= NARROW).all(), case
    data = env.rollout(4 * EPISODE, break_when_any_done=False, auto_reset=False, tensordict=reset)
    drawn = data["next", "domain", kind.field]
    assert torch.equal(drawn[:, -1], _entry(env.base_env.domain_values([kind.field])[kind.field], kind)), case
    assert (_distance(drawn, kind.nominal) > WIDE).any(), case
    low, high = kind.param(kind.wide).support()
    assert ((drawn >= low) & (drawn <= high)).all(), case
    if writer != "levels":  # the data report the written value the physics follow
        written = data["next", "curriculum", kind.target.replace(".", "/")][:, -1]
        assert torch.allclose(written, kind.wide.expand_as(written)), case


def test_every_writer_in_every_mode_on_every_kind_of_distribution_is_honoured_or_refused(bases: dict):
    """when='reset' and 'interval' without cycle draw from the written values (honoured); 'startup', a drawn or a
    given cycle would never draw them again: refused when the specs are built, naming the writer, the target and the
    mode. Every writer kind x every mode x every kind of domain distribution."""
    assert {type(kind.param(kind.narrow)) for kind in KINDS.values()} == set(DomainParam.__subclasses__())
    torch.manual_seed(0)  # the random actions
    for (name, kind), mode, writer in ((k, m, w) for k in KINDS.items() for m in MODES for w in WRITERS):
        case = f"{name} x {mode} x {writer}"
        env = _env(bases, name, mode, writer)
        words = MODES[mode][1]
        if words is None:
            _check_honoured(env, kind, writer, case)
            continue
        who = "DifficultyLevels" if writer == "levels" else "Curriculum"
        expected = f"{who} sets {re.escape(repr(kind.target))} of a DomainRandomization with {re.escape(words)}"
        with pytest.raises(ValueError, match=expected + ".* never drawn.*when='reset' or when='interval'"):
            env.observation_spec  # noqa: B018 (the specs are built here)


def test_target_names_lists_no_writer_for_a_distribution_never_drawn_again(bases: dict):
    for mode, (_, words) in MODES.items():
        env = _env(bases, "uniform", mode, "linear")
        env.transform.pop()  # the table of what a writer could set, before one is added
        (row,) = [row for row in target_names(env) if row.name == "domain.mass.halfspan"]
        assert row.writers == (() if words else ("Curriculum", "DifficultyLevels")), mode


def test_levels_on_a_cycle_are_refused_not_crashed_at_the_first_reset():
    randomization = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.0)], cycle=3, seed=0)
    levels = DifficultyLevels(2, {"domain.mass.halfspan": [0.0, 0.5]})
    env = TransformedEnv(
        PendulumEnv(batch_size=[BATCH]),
        Compose(StepCounter(EPISODE), TaskTransform(swing_up_task()), randomization, levels),
    )
    with pytest.raises(ValueError, match=r"DifficultyLevels sets 'domain\.mass\.halfspan' .* cycle=3"):
        env.reset()
    assert randomization.params["mass"].halfspan.shape == ()  # refused before the levels made it per env


# ------------------------------------------------------------------------------------------------ together
def _pendulum(*writers, param: DomainParam | None = None) -> TransformedEnv:
    param = UniformDomainParam("mass", mean=1.0, halfspan=0.0) if param is None else param
    randomization = DomainRandomization([param], seed=0)
    task = TaskTransform(swing_up_task())
    return TransformedEnv(
        PendulumEnv(batch_size=[BATCH], seed=0), Compose(StepCounter(5), task, randomization, *writers)
    )


def _lighter(lowest: float) -> Curriculum:
    return Curriculum({"domain.mass.mean": linear(1.0, lowest, 0, 40)})  # alone: masses of `lowest` at least


def _wider_levels() -> DifficultyLevels:
    return DifficultyLevels(2, {"domain.mass.halfspan": [0.0, 0.5]}, rule=_up)  # alone: masses of 0.5 at least


MEAN_AT = r"the schedule of 'domain\.mass\.mean' at frame \d+"
LEVEL_1 = r"level 1 of 'domain\.mass\.halfspan'"
TOGETHER = r".* can write .* together into .* can write -0\.\d+ into 'mass'"
EITHER = f"Curriculum: {MEAN_AT} with {LEVEL_1} .a DifficultyLevels|DifficultyLevels: {LEVEL_1} with {MEAN_AT} .a Curr"

# writers of one distribution, each accepted alone: with `lowest` 0.3 their values together reach a mass <= 0 (the
# combination named), with 0.6 they stay above 0.1. (writers of `lowest`, the refusal's combination)
TOGETHER_CASES = {
    "curriculum, then levels": (lambda lowest: [_lighter(lowest), _wider_levels()], EITHER),
    "levels, then curriculum": (lambda lowest: [_wider_levels(), _lighter(lowest)], EITHER),
    "two curricula": (
        lambda lowest: [
            _lighter(lowest),
            Curriculum({"domain.mass.halfspan": staged({0: 0.0, 4 * BATCH: 0.5})}, curriculum_key="widen"),
        ],
        rf"Curriculum: ({MEAN_AT} with the schedule of 'domain\.mass\.halfspan' at frame {4 * BATCH} .another Curr"
        rf"|the schedule of 'domain\.mass\.halfspan' at frame {4 * BATCH} with {MEAN_AT} .another Curriculum)",
    ),
    "a gated schedule and levels": (
        lambda lowest: [
            Curriculum({"domain.mass.halfspan": gated([0.0, 0.25, 0.5], "step_count", threshold=0.0, window=1)}),
            DifficultyLevels(2, {"domain.mass.mean": [1.0, lowest]}, rule=_up),
        ],
        r"Curriculum: the schedule of 'domain\.mass\.halfspan' at stage 2 with level 1 of 'domain\.mass\.mean' .a Diff"
        r"|DifficultyLevels: level 1 of 'domain\.mass\.mean' with the schedule of 'domain\.mass\.halfspan' at stage 2",
    ),
}


@pytest.mark.parametrize("case", list(TOGETHER_CASES))
def test_writers_of_one_distribution_are_checked_together_at_every_combination(case: str):
    """Each writer alone is accepted; together they are refused when some combination of their values leaves the
    field, naming it (among them the audit's case: a Curriculum lowering the mean, levels widening the range), and
    run, drawing from every combination, when none does."""
    writers, named = TOGETHER_CASES[case]
    for alone in writers(0.3):
        _pendulum(alone).observation_spec  # noqa: B018 (the specs are built here)
    with pytest.raises(ValueError, match=f"({named}){TOGETHER}"):
        _pendulum(*writers(0.3)).observation_spec  # noqa: B018
    masses = _pendulum(*writers(0.6)).rollout(30, break_when_any_done=False)["next", "domain", "mass"]
    assert (masses >= 0.1 - 1e-12).all() and (masses <= 1.5 + 1e-12).all()
    assert (masses < 0.5).any()  # a lowered mean with a widened range: both writers' values drawn together


def test_a_clipping_bound_scheduled_with_the_mean_is_checked_between_breakpoints():
    """clamp(mean - halfspan, clip_lo) is not convex along a ramp of both: at frame 52 the mass range reaches -0.012,
    though every breakpoint's range stays above 0.8. The mixed corners of the segment find it."""
    param = UniformDomainParam("mass", mean=2.0, halfspan=1.0, clip_lo=-1.0)
    schedules = {"domain.mass.mean": linear(2.0, 0.0, 0, 100), "domain.mass.clip_lo": linear(-1.0, 0.9, 0, 100)}
    with pytest.raises(ValueError, match=r"between frames 0 and 99 \(mixed\) can write .* into 'mass'"):
        _pendulum(Curriculum(schedules), param=param).observation_spec  # noqa: B018


def test_two_curricula_on_one_buffer_are_refused():
    second = Curriculum({"domain.mass.halfspan": linear(0.0, 0.3, 0, 100)}, curriculum_key="second")
    env = _pendulum(Curriculum({"domain.mass.halfspan": linear(0.0, 0.5, 0, 100)}), second)
    with pytest.raises(ValueError, match=r"Curriculum sets 'domain\.mass\.halfspan', which a Curriculum .*one owner"):
        env.observation_spec  # noqa: B018


@pytest.mark.parametrize("levels_first", [False, True])
def test_a_vector_schedule_goes_with_per_env_levels_in_either_order(levels_first: bool):
    """A Curriculum's value of one env's shape, into a distribution the levels made per env."""
    mean = Curriculum({"domain.gravity.mean": linear([0.0, 0.0, -9.81], [0.0, 0.0, -5.0], 0, 40)})
    levels = DifficultyLevels(2, {"domain.gravity.halfspan": [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]}, rule=_up)
    env = _hopper()
    env.append_transform(DomainRandomization([UniformDomainParam("gravity", [0.0, 0.0, -9.81], 0.0)], seed=0))
    for writer in [levels, mean] if levels_first else [mean, levels]:
        env.append_transform(writer)
    gravity = env.rollout(4 * EPISODE, break_when_any_done=False)["next", "domain", "gravity"]
    assert gravity.shape == (BATCH, 4 * EPISODE, 3)
    assert (gravity[..., 2] >= -9.81 - 1.0 - 1e-9).all() and (gravity[:, -1, 2] > -9.0).all()


# ------------------------------------------------------------------------------------------------ refused draws
def _state(randomization: DomainRandomization) -> dict:
    return copy.deepcopy(dict(randomization.state_dict()))


def _same(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for key in a:
        x, y = a[key], b[key]
        if isinstance(x, dict):
            if not _same(x, y):
                return False
        elif isinstance(x, torch.Tensor):
            if not (x.shape == y.shape and torch.equal(x, y)):
                return False
        elif x != y:
            return False
    return True


def _randomized(cycle: int | None) -> tuple[TransformedEnv, DomainRandomization]:
    randomization = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.5)], cycle=cycle, seed=0)
    return TransformedEnv(
        PendulumEnv(batch_size=[BATCH], seed=0), Compose(StepCounter(5), randomization)
    ), randomization


@pytest.mark.parametrize("cycle", [None, 3])
def test_a_draw_the_env_refuses_changes_nothing(cycle: int | None):
    """A distribution written past the field's range by hand (no writer can: the build checks them): the env refuses
    the draw; the transform's drawn values (the entries' and the checkpoints' source), its stored set and index, its
    counters and its generator stay as they were, and so does the env. The run then goes on as if it never was."""
    env, randomization = _randomized(cycle)
    twin, _ = _randomized(cycle)
    if cycle is None:  # a later draw is refused
        env.reset()
        twin.reset()
    else:  # the first draw, which fills the stored set, is refused
        env.observation_spec  # noqa: B018 (the buffers get the env's batch)
        twin.observation_spec  # noqa: B018
    before, physics = _state(randomization), env.base_env.domain_values()
    mean = randomization.params["mass"].mean
    mean.fill_(-5.0)
    with pytest.raises(ValueError, match=r"values\['mass'\] of env \d is -\d"):
        env.reset()
    assert _same(_state(randomization), {**before, "params.mass.mean": mean})
    assert all(torch.equal(value, env.base_env.domain_values()[name]) for name, value in physics.items())
    mean.fill_(1.0)
    assert torch.equal(env.reset()["domain", "mass"], twin.reset()["domain", "mass"])
    assert torch.equal(randomization.drawn.mass, env.base_env.domain_values(["mass"])["mass"])
