"""Reset steps: draws a batched MuJoCo env makes at a reset beyond noise, run in order for the envs that reset.

A :class:`~torchtasks.envs.Resets` holds ``steps``: after the default state (``qpos0`` or a keyframe) and its noise,
each reset env runs them in order, drawing from its own generator. They are what the DeepMind Control Suite's
``initialize_episode`` methods do, as data: joints drawn in their ranges (:class:`UniformJoints`, dm_control's
``randomize_limited_and_rotational_joints``), around a pose (:class:`NormalJoints`), a random orientation
(:class:`RandomOrientation`), a joint copied (:class:`CopyJoints`), a model field drawn per env through the domain
fields (:class:`DrawDomain`: a target's position, with the samplers :class:`Box`, :class:`Ring`, :class:`AxisAngle`,
:class:`Choice`), draws repeated until nothing touches (:class:`UntilContactFree`), a floating base raised until it
touches nothing (:class:`RaiseUntilContactFree`) and a few physics steps with zero controls (:class:`Settle`).

Each step is a frozen dataclass (compared and saved as text in checkpoints) that :meth:`ResetStep.resolve` turns into
a function of the model's addresses once; the env calls it with a :class:`ResetContext`, the ids of the envs to draw
for and their generators. Draws loop over the reset envs (each draws from its own generator, so an env's draws do not
depend on which others reset); the writes are array operations. A reset to given states
(:meth:`~torchtasks.envs.BatchedMujocoEnv.set_reset_states`) runs only the steps that write model fields alone
(:class:`DrawDomain`, also inside :class:`UntilContactFree`, then drawn once): the given state replaces every draw of
``qpos`` and ``qvel``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from torchtasks._optional import missing_extra

try:
    import mujoco
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.reset_steps", _error) from _error

from torchtasks.domain.fields import check_in_field
from torchtasks.envs.mujoco_domain import domain_field
from torchtasks.envs.mujoco_model import object_id

__all__ = [
    "AxisAngle",
    "Box",
    "Choice",
    "CopyJoints",
    "DrawDomain",
    "NormalJoints",
    "RaiseUntilContactFree",
    "RandomOrientation",
    "ResetContext",
    "ResetStep",
    "Ring",
    "Sampler",
    "Settle",
    "UniformJoints",
    "UntilContactFree",
]

_FREE, _BALL, _SLIDE, _HINGE = (int(getattr(mujoco.mjtJoint, f"mjJNT_{t}")) for t in ("FREE", "BALL", "SLIDE", "HINGE"))
#: a resolved step: (context, ids of the envs reset, their generators) -> None
Apply = Callable[["ResetContext", np.ndarray, Sequence[np.random.Generator]], None]


class ResetContext:
    """What a reset step works on: the env's simulations, of which it touches the rows ``ids`` it is given.

    Built by the env for each reset. ``qpos``, ``qvel`` and ``data(name)`` are live ``[num_envs, ...]`` arrays of
    the batch; ``forward(ids, stage)`` runs MuJoCo's forward stages for ``ids`` (controls and activations are those
    of the reset: zero or the keyframe's), ``contacts(ids)`` is their ``ncon``, ``write_domain(name, ids, values)``
    writes a domain field of ``ids`` (``values`` ``[len(ids), *shape]``), ``settle(ids, nstep)`` steps them
    ``nstep`` substeps and sets their clock back to 0.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        qpos: np.ndarray,
        qvel: np.ndarray,
        data: Callable[[str], np.ndarray],
        forward: Callable[[np.ndarray, int], None],
        write_domain: Callable[[str, np.ndarray, np.ndarray], None],
        settle: Callable[[np.ndarray, int], None],
    ) -> None:
        self.model = model
        self.qpos = qpos
        self.qvel = qvel
        self.data = data
        self.forward = forward
        self.write_domain = write_domain
        self.settle = settle

    def contacts(self, ids: np.ndarray) -> np.ndarray:
        """The number of contacts of each env ``ids`` after its last forward (``ncon``)."""
        return self.data("ncon").reshape(-1)[ids]


class ResetStep:
    """One step of a reset; subclasses are frozen dataclasses with :meth:`resolve`."""

    #: whether the step writes ``qpos``/``qvel`` (skipped by a reset to given states)
    writes_state: bool = True

    def resolve(self, model: mujoco.MjModel) -> Apply:
        """Check the step against ``model`` (names, joint types, field shapes) and return its function."""
        raise NotImplementedError

    def resolve_model_part(self, model: mujoco.MjModel) -> Apply | None:
        """The part of the step a reset to given states runs: what writes model fields alone (None: nothing)."""
        return None if self.writes_state else self.resolve(model)


def _finite(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise TypeError(f"{name} must be a finite real number, got {value!r}")
    return float(value)


def _pair(value: object, name: str) -> tuple[float, float]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
        raise TypeError(f"{name} must be a pair of finite numbers, got {value!r}")
    return _finite(value[0], f"{name}[0]"), _finite(value[1], f"{name}[1]")


def _names(value: object, argument: str) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise TypeError(f"{argument} must be a sequence of joint names, got {value!r}")
    return tuple(value)


def _joint(model: mujoco.MjModel, name: str, argument: str, types: tuple[int, ...], what: str) -> int:
    joint = object_id(model, "joint", name, argument)
    if int(model.jnt_type[joint]) not in types:
        raise ValueError(f"{argument}: joint {name!r} is not {what}")
    return joint


def _attempts(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"{name} must be a positive int, got {value!r}")
    return int(value)


def _draws(generators: Sequence[np.random.Generator], draw: Callable[[np.random.Generator], Any]) -> np.ndarray:
    # the Python loop over the envs reset: each draws from its own generator, in the declared order
    return np.array([draw(rng) for rng in generators])


# ---------------------------------------------------------------------------------------------------- joints
@dataclass(frozen=True)
class UniformJoints(ResetStep):
    """Draw hinge and slide joint positions uniformly: ``qpos[joint] ~ U(low, high)``.

    ``joints``: ``None`` draws every limited hinge or slide in its range and every unlimited hinge in ``[-pi, pi)``
    (dm_control's ``randomize_limited_and_rotational_joints`` for these joints; unlimited slides are not drawn);
    a sequence of names draws those joints by the same rule (an unlimited slide needs a range); a mapping
    ``{joint: (low, high)}`` gives the ranges.

    Example:
        >>> UniformJoints({"slider": (-0.1, 0.1)}).joints
        {'slider': (-0.1, 0.1)}
    """

    joints: Sequence[str] | Mapping[str, tuple[float, float]] | None = None

    def resolve(self, model: mujoco.MjModel) -> Apply:
        rows: list[tuple[int, float, float]] = []
        if self.joints is None:
            for joint in range(model.njnt):
                kind, limited = int(model.jnt_type[joint]), bool(model.jnt_limited[joint])
                if kind in (_HINGE, _SLIDE) and limited:
                    rows.append((int(model.jnt_qposadr[joint]), *map(float, model.jnt_range[joint])))
                elif kind == _HINGE:
                    rows.append((int(model.jnt_qposadr[joint]), -math.pi, math.pi))
        else:
            ranges = dict(self.joints) if isinstance(self.joints, Mapping) else None
            names = tuple(ranges) if ranges is not None else _names(self.joints, "UniformJoints joints")
            for name in names:
                joint = _joint(model, name, "UniformJoints joints", (_HINGE, _SLIDE), "a hinge or slide joint")
                if ranges is not None:
                    low, high = _pair(ranges[name], f"UniformJoints joints[{name!r}]")
                    if low > high:
                        raise ValueError(f"UniformJoints joints[{name!r}] must have low <= high, got {ranges[name]}")
                elif model.jnt_limited[joint]:
                    low, high = map(float, model.jnt_range[joint])
                elif int(model.jnt_type[joint]) == _HINGE:
                    low, high = -math.pi, math.pi
                else:
                    raise ValueError(f"UniformJoints joints: slide {name!r} is unlimited: give its range")
                rows.append((int(model.jnt_qposadr[joint]), low, high))
        columns = np.array([row[0] for row in rows], dtype=np.int64)
        low = np.array([row[1] for row in rows])
        high = np.array([row[2] for row in rows])

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            if columns.size:
                context.qpos[np.ix_(ids, columns)] = _draws(generators, lambda rng: rng.uniform(low, high))

        return apply


@dataclass(frozen=True)
class NormalJoints(ResetStep):
    """Draw hinge and slide joint positions around a pose: ``qpos[joint] = mean + std * N(0, 1)``.

    Example:
        >>> import math
        >>> NormalJoints({"hinge_1": (math.pi, 0.01)}).joints["hinge_1"][1]
        0.01
    """

    joints: Mapping[str, tuple[float, float]]

    def resolve(self, model: mujoco.MjModel) -> Apply:
        if not isinstance(self.joints, Mapping) or not self.joints:
            raise TypeError(f"NormalJoints joints must map joint names to (mean, std), got {self.joints!r}")
        columns, mean, std = [], [], []
        for name, value in self.joints.items():
            joint = _joint(model, name, "NormalJoints joints", (_HINGE, _SLIDE), "a hinge or slide joint")
            m, s = _pair(value, f"NormalJoints joints[{name!r}]")
            if s < 0:
                raise ValueError(f"NormalJoints joints[{name!r}]: the std must be >= 0, got {s}")
            columns.append(int(model.jnt_qposadr[joint]))
            mean.append(m)
            std.append(s)
        cols, mu, sigma = np.array(columns), np.array(mean), np.array(std)

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            noise = _draws(generators, lambda rng: rng.standard_normal(len(cols)))
            context.qpos[np.ix_(ids, cols)] = mu + sigma * noise

        return apply


#: how :class:`RandomOrientation` draws a quaternion: four numbers normalised
_ORIENTATIONS = {
    # uniform on rotations: a normalised 4D Gaussian
    "uniform": lambda rng: rng.standard_normal(4),
    # dm_control's rule for free joints: rand(4) normalised (all components >= 0; not uniform on rotations)
    "positive": lambda rng: rng.random(4),
}


@dataclass(frozen=True)
class RandomOrientation(ResetStep):
    """Draw a free or ball joint's orientation: ``"uniform"`` on rotations, or ``"positive"`` (a normalised
    ``U[0, 1)^4``, all components >= 0: dm_control's rule for a humanoid's free joint). A free joint keeps its
    position.

    Example:
        >>> RandomOrientation("root", "positive").distribution
        'positive'
    """

    joint: str
    distribution: str = "uniform"

    def resolve(self, model: mujoco.MjModel) -> Apply:
        if self.distribution not in _ORIENTATIONS:
            raise ValueError(
                f"RandomOrientation distribution must be one of {list(_ORIENTATIONS)}, got {self.distribution!r}"
            )
        joint = _joint(model, self.joint, "RandomOrientation joint", (_FREE, _BALL), "a free or ball joint")
        start = int(model.jnt_qposadr[joint]) + (3 if int(model.jnt_type[joint]) == _FREE else 0)
        columns = np.arange(start, start + 4)
        draw = _ORIENTATIONS[self.distribution]

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            quaternions = _draws(generators, draw)
            context.qpos[np.ix_(ids, columns)] = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)

        return apply


@dataclass(frozen=True)
class CopyJoints(ResetStep):
    """Set joints to the current positions of others: ``{joint: source}`` (manipulator's finger follows its thumb).

    Example:
        >>> CopyJoints({"finger": "thumb"}).joints
        {'finger': 'thumb'}
    """

    joints: Mapping[str, str]

    def resolve(self, model: mujoco.MjModel) -> Apply:
        if not isinstance(self.joints, Mapping) or not self.joints:
            raise TypeError(f"CopyJoints joints must map joint names to joint names, got {self.joints!r}")
        kinds = (_HINGE, _SLIDE)
        targets, sources = [], []
        for target, source in self.joints.items():
            if not isinstance(source, str):
                raise TypeError(f"CopyJoints joints[{target!r}] must be a joint name, got {source!r}")
            for name, row in ((target, targets), (source, sources)):
                joint = _joint(model, name, "CopyJoints joints", kinds, "a hinge or slide joint")
                row.append(int(model.jnt_qposadr[joint]))
        to, of = np.array(targets), np.array(sources)

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            context.qpos[np.ix_(ids, to)] = context.qpos[np.ix_(ids, of)]

        return apply


# ---------------------------------------------------------------------------------------------------- samplers
class Sampler:
    """Draws one env's value of a domain field from its generator, starting from the field's nominal value."""

    def check(self, shape: tuple[int, ...], field: str) -> None:
        """Refuse a field of a shape the sampler cannot fill (``ValueError`` naming it)."""
        raise NotImplementedError

    def draw(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        """A new value: ``nominal`` (a copy) with the sampled components."""
        raise NotImplementedError

    def support(self, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The smallest and the largest value each component of a draw can take (elementwise, ``nominal``'s shape),
        which the field's range must hold; unbounded (``-inf``, ``inf``) unless a sampler says."""
        return np.full(nominal.shape, -math.inf), np.full(nominal.shape, math.inf)


def _numbers(value: object, name: str) -> tuple[float, ...]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or not value:
        raise TypeError(f"{name} must be a non-empty sequence of finite numbers, got {value!r}")
    return tuple(_finite(v, name) for v in value)


def _indices(value: object, count: int, name: str) -> None:
    if (
        isinstance(value, (str, bytes))
        or not isinstance(value, Sequence)
        or len(value) != count
        or not all(isinstance(a, numbers.Integral) and not isinstance(a, bool) and a >= 0 for a in value)
        or len(set(value)) != count
    ):
        raise ValueError(f"{name} must be {count} distinct indices (ints >= 0), got {value!r}")


def _axes(axes: Sequence[int], shape: tuple[int, ...], field: str, who: str) -> None:
    if len(shape) != 1 or not all(a < shape[0] for a in axes):
        raise ValueError(f"{who} axes {axes} do not index domain field {field!r} of shape {shape}")


@dataclass(frozen=True)
class Box(Sampler):
    """Components ``axes`` (default: the first ``len(low)``) drawn uniformly in ``[low, high)``; the others nominal.

    Example:
        >>> import numpy as np
        >>> Box((-0.4, -0.4), (0.4, 0.4)).draw(np.random.default_rng(0), np.array([0.0, 0.0, 0.1])).shape
        (3,)
    """

    low: Sequence[float]
    high: Sequence[float]
    axes: Sequence[int] | None = None

    def __post_init__(self) -> None:
        low, high = _numbers(self.low, "Box low"), _numbers(self.high, "Box high")
        if len(low) != len(high) or any(a > b for a, b in zip(low, high, strict=True)):
            raise ValueError(f"Box needs low <= high with one entry per axis, got {self.low}, {self.high}")
        if self.axes is not None:
            _indices(self.axes, len(low), "Box axes (one per entry of low)")

    def check(self, shape: tuple[int, ...], field: str) -> None:
        _axes(range(len(self.low)) if self.axes is None else self.axes, shape, field, "Box")

    def draw(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        value = nominal.copy()
        value[list(range(len(self.low)) if self.axes is None else self.axes)] = rng.uniform(self.low, self.high)
        return value

    def support(self, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lowest, highest = nominal.copy(), nominal.copy()
        axes = list(range(len(self.low)) if self.axes is None else self.axes)
        lowest[axes], highest[axes] = self.low, self.high
        return lowest, highest


@dataclass(frozen=True)
class Ring(Sampler):
    """A point around ``centre`` in the plane of components ``axes``: ``centre + r (sin a, cos a)`` with
    ``a ~ U(angle)`` and ``r ~ U(radius)`` (a number: a fixed radius), drawn in that order (dm_control's reacher and
    finger targets).

    Example:
        >>> import numpy as np
        >>> value = Ring((0.0, 0.0), 0.1).draw(np.random.default_rng(0), np.zeros(3))
        >>> round(float(np.hypot(value[0], value[1])), 12)
        0.1
    """

    centre: Sequence[float]
    radius: float | tuple[float, float]
    axes: tuple[int, int] = (0, 1)
    angle: tuple[float, float] = (0.0, 2 * math.pi)

    def __post_init__(self) -> None:
        _pair(self.centre, "Ring centre")
        _pair(self.angle, "Ring angle")
        _indices(self.axes, 2, "Ring axes")
        if isinstance(self.radius, numbers.Real) and not isinstance(self.radius, bool):
            low = high = _finite(self.radius, "Ring radius")
        else:
            low, high = _pair(self.radius, "Ring radius")
        if not 0 <= low <= high:
            raise ValueError(f"Ring radius must be >= 0 (low <= high), got {self.radius}")

    def check(self, shape: tuple[int, ...], field: str) -> None:
        _axes(self.axes, shape, field, "Ring")

    def draw(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        angle = rng.uniform(*self.angle)
        radius = self.radius if isinstance(self.radius, numbers.Real) else rng.uniform(*self.radius)
        value = nominal.copy()
        value[self.axes[0]] = self.centre[0] + radius * math.sin(angle)
        value[self.axes[1]] = self.centre[1] + radius * math.cos(angle)
        return value

    def support(self, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # the square around the circle of the largest radius (whatever the angles)
        radius = self.radius if isinstance(self.radius, numbers.Real) else self.radius[1]
        lowest, highest = nominal.copy(), nominal.copy()
        for axis, centre in zip(self.axes, self.centre, strict=True):
            lowest[axis], highest[axis] = centre - radius, centre + radius
        return lowest, highest


@dataclass(frozen=True)
class AxisAngle(Sampler):
    """A quaternion ``(cos a/2, sin a/2 * axis)`` of a turn about the unit ``axis`` by ``a ~ U(angle)``.

    Example:
        >>> import numpy as np
        >>> AxisAngle((0.0, 1.0, 0.0), (0.0, 0.0)).draw(np.random.default_rng(0), np.zeros(4)).tolist()
        [1.0, 0.0, 0.0, 0.0]
    """

    axis: Sequence[float]
    angle: tuple[float, float] = (-math.pi, math.pi)

    def __post_init__(self) -> None:
        axis = [_finite(v, "AxisAngle axis") for v in self.axis]
        if len(axis) != 3 or abs(math.hypot(*axis) - 1.0) > 1e-12:
            raise ValueError(f"AxisAngle axis must be a unit 3-vector, got {self.axis}")
        _pair(self.angle, "AxisAngle angle")

    def check(self, shape: tuple[int, ...], field: str) -> None:
        if shape != (4,):
            raise ValueError(f"AxisAngle draws a quaternion; domain field {field!r} has shape {shape}")

    def draw(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        half = 0.5 * rng.uniform(*self.angle)
        return np.array([math.cos(half), *(math.sin(half) * np.asarray(self.axis, dtype=float))])

    def support(self, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        bound = np.array([1.0, *np.abs(np.asarray(self.axis, dtype=float))])
        return -bound, bound


@dataclass(frozen=True)
class Choice(Sampler):
    """One of several samplers, chosen with probabilities: ``Choice(((0.2, near), (0.8, far)))``.

    Example:
        >>> import numpy as np
        >>> near, far = Box((-0.3, -0.3), (0.3, 0.3)), Box((-2.0, -2.0), (2.0, 2.0))
        >>> Choice(((0.2, near), (0.8, far))).draw(np.random.default_rng(0), np.zeros(3)).shape
        (3,)
    """

    options: Sequence[tuple[float, Sampler]]

    def __post_init__(self) -> None:
        if not self.options or not all(
            isinstance(o, tuple) and len(o) == 2 and isinstance(o[1], Sampler) for o in self.options
        ):
            raise TypeError(f"Choice options must be (probability, Sampler) pairs, got {self.options!r}")
        weights = [_finite(p, "Choice probability") for p, _ in self.options]
        if any(p < 0 for p in weights) or abs(sum(weights) - 1.0) > 1e-9:
            raise ValueError(f"Choice probabilities must be >= 0 and sum to 1, got {weights}")

    def check(self, shape: tuple[int, ...], field: str) -> None:
        for _, sampler in self.options:
            sampler.check(shape, field)

    def draw(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        u, total = rng.random(), 0.0
        for probability, sampler in self.options:
            total += probability
            if u < total:
                return sampler.draw(rng, nominal)
        return self.options[-1][1].draw(rng, nominal)

    def support(self, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        supports = [sampler.support(nominal) for _, sampler in self.options]
        return np.min([low for low, _ in supports], axis=0), np.max([high for _, high in supports], axis=0)


@dataclass(frozen=True)
class DrawDomain(ResetStep):
    """Draw a domain field of each reset env (``"geom_pos:target"``, ``"body_quat:target_ball"``) with a
    :class:`Sampler`, from its nominal value. The value stays until the next draw or ``set_domain``, and is saved
    with the env's other domain values. A sampler that could draw a value the field does not allow (a negative
    damping: see the sampler's ``support``) is refused when the env is built.

    Example:
        >>> DrawDomain("geom_pos:target", Ring((0.0, 0.0), (0.05, 0.2))).field
        'geom_pos:target'
    """

    field: str
    sampler: Sampler
    writes_state = False

    def resolve(self, model: mujoco.MjModel) -> Apply:
        if not isinstance(self.sampler, Sampler):
            raise TypeError(f"DrawDomain sampler must be a Sampler, got {type(self.sampler).__name__}")
        field = domain_field(model, self.field, "DrawDomain field")
        nominal = field.nominal.numpy().copy()
        self.sampler.check(nominal.shape, self.field)
        # what set_domain would refuse (a negative damping) is refused here, before any reset draws it
        lowest, highest = self.sampler.support(nominal)
        check_in_field(field, torch.from_numpy(lowest), torch.from_numpy(highest), repr(self), "narrow the sampler")
        name, sampler = self.field, self.sampler

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            context.write_domain(name, ids, _draws(generators, lambda rng: sampler.draw(rng, nominal)))

        return apply


# ---------------------------------------------------------------------------------------------------- contacts
#: the forward stage that computes the contacts (collision runs in the position stage)
_POSITION = int(mujoco.mjtStage.mjSTAGE_POS)


@dataclass(frozen=True)
class UntilContactFree(ResetStep):
    """Run ``steps`` again for every env whose drawn state has a contact, until none has (at most ``attempts``
    times; then ``RuntimeError``): dm_control's rejection sampling of ball_in_cup, finger, humanoid, manipulator.

    Example:
        >>> UntilContactFree((UniformJoints(),)).attempts
        1000
    """

    steps: Sequence[ResetStep]
    attempts: int = 1000

    def resolve(self, model: mujoco.MjModel) -> Apply:
        steps = self.steps
        if isinstance(steps, (str, bytes)) or not isinstance(steps, Sequence) or not steps:
            raise TypeError(f"UntilContactFree steps must be a non-empty sequence of ResetSteps, got {steps!r}")
        if not all(isinstance(step, ResetStep) for step in steps):
            raise TypeError(f"UntilContactFree steps must be ResetSteps, got {steps!r}")
        attempts = _attempts(self.attempts, "UntilContactFree attempts")
        inner = [step.resolve(model) for step in self.steps]

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            pending, rngs = ids, list(generators)
            for _ in range(attempts):
                for step in inner:
                    step(context, pending, rngs)
                context.forward(pending, _POSITION)
                touching = context.contacts(pending) > 0
                if not touching.any():
                    return
                pending = pending[touching]
                rngs = [rng for rng, again in zip(rngs, touching.tolist(), strict=True) if again]
            raise RuntimeError(
                f"UntilContactFree: envs {pending.tolist()} still touched something after {attempts} draws"
            )

        return apply

    def resolve_model_part(self, model: mujoco.MjModel) -> Apply | None:
        # a reset to given states draws the model fields of the steps once (a target), without the rejection
        parts = [part for step in self.steps if (part := step.resolve_model_part(model)) is not None]
        if not parts:
            return None

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            for part in parts:
                part(context, ids, generators)

        return apply


@dataclass(frozen=True)
class RaiseUntilContactFree(ResetStep):
    """Place a free joint at height ``start``, then raise it by ``step`` until the model touches nothing (dm_control's
    quadruped: from 0 in 1 cm steps, the height accumulated as ``z += step``); at most ``attempts`` heights.

    Example:
        >>> RaiseUntilContactFree("root").step
        0.01
    """

    joint: str
    step: float = 0.01
    start: float = 0.0
    attempts: int = 10000

    def resolve(self, model: mujoco.MjModel) -> Apply:
        joint = _joint(model, self.joint, "RaiseUntilContactFree joint", (_FREE,), "a free joint")
        column = int(model.jnt_qposadr[joint]) + 2
        step = _finite(self.step, "RaiseUntilContactFree step")
        start = _finite(self.start, "RaiseUntilContactFree start")
        if step <= 0:
            raise ValueError(f"RaiseUntilContactFree step must be > 0, got {self.step}")
        attempts = _attempts(self.attempts, "RaiseUntilContactFree attempts")

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            pending, height = ids, np.full(ids.size, start)
            for _ in range(attempts):
                context.qpos[pending, column] = height
                context.forward(pending, _POSITION)
                touching = context.contacts(pending) > 0
                if not touching.any():
                    return
                pending, height = pending[touching], height[touching] + step
            raise RuntimeError(f"RaiseUntilContactFree: envs {pending.tolist()} still touched after {attempts} heights")

        return apply


@dataclass(frozen=True)
class Settle(ResetStep):
    """Step the reset envs ``substeps`` MuJoCo substeps with the reset's controls (zero, or the keyframe's), then
    set their clock back to 0 (dm_control's cheetah starts from its drawn pose after 200 such steps).

    Example:
        >>> Settle(200).substeps
        200
    """

    substeps: int

    def resolve(self, model: mujoco.MjModel) -> Apply:
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"Settle substeps must be a positive int, got {self.substeps!r}")
        substeps = self.substeps

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            context.settle(ids, substeps)

        return apply
