"""What a batched MuJoCo env is, as data: its model, readings, actions, resets and control step.

A :class:`MujocoDeclaration` holds everything :class:`~torchtasks.envs.BatchedMujocoEnv` builds an env from: the
compiled model, the entries it observes and the task-state entries (each a list of
:mod:`~torchtasks.envs.readings`), how an action becomes controls (:class:`Actions`), how a reset draws the initial
state (:class:`Resets`, :class:`Noise`, :class:`FreeJointRanges`), the substeps of a step and the stage the readings
are taken at. The Gymnasium presets are declarations (:mod:`torchtasks.envs.gymnasium_v5`), so is a user's robot:
one engine reads them all and never branches on which one it runs.

:func:`declare` checks what a user passes and resolves every name against the model once (the closest names on a
miss); the engine then only runs array operations.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from torchtasks._optional import missing_extra

try:
    import mujoco
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.mujoco_declaration", _error) from _error

from torchtasks.envs import readings as _readings
from torchtasks.envs.mujoco_model import load_model, model_label, object_id, object_names
from torchtasks.envs.readings import Reading, Resolved
from torchtasks.envs.reset_steps import Apply, ResetStep

__all__ = [
    "Actions",
    "FreeJointRanges",
    "MujocoDeclaration",
    "Noise",
    "Resets",
    "declare",
]

#: the stages readings can be taken at after a step
Stage = Literal["velocity", "step"]
#: where the contact forces (``cfrc_ext``) of a step come from
ContactForces = Literal["forward", "after_step"]

#: sensors whose evaluation runs ``mj_rnePostConstraint`` in ``mj_forward``, and so fills ``cfrc_ext``
_RNE_POST_SENSORS = frozenset(
    int(kind)
    for kind in (
        mujoco.mjtSensor.mjSENS_ACCELEROMETER,
        mujoco.mjtSensor.mjSENS_FORCE,
        mujoco.mjtSensor.mjSENS_TORQUE,
        mujoco.mjtSensor.mjSENS_FRAMELINACC,
        mujoco.mjtSensor.mjSENS_FRAMEANGACC,
    )
)
#: the name of the sensor the env adds to a model whose readings need contact forces and that has no such sensor
CONTACT_FORCE_SENSOR = "torchtasks_contact_forces"

_JOINT_QPOS = {0: 7, 1: 4, 2: 1, 3: 1}  # mjtJoint: free, ball, slide, hinge
_JOINT_QVEL = {0: 6, 1: 3, 2: 1, 3: 1}


def _finite(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise TypeError(f"{name} must be a finite real number, got {value!r}")
    return float(value)


def _range(value: object, name: str) -> tuple[float, float]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
        raise TypeError(f"{name} must be a (low, high) pair of finite numbers, got {value!r}")
    low, high = _finite(value[0], f"{name}[0]"), _finite(value[1], f"{name}[1]")
    if low > high:
        raise ValueError(f"{name} must have low <= high, got {value!r}")
    return low, high


@dataclass(frozen=True)
class Noise:
    """Noise drawn per env at a reset: ``uniform`` on ``[-scale, scale]`` or ``normal`` with std ``scale``.

    ``mode="add"`` adds the draw to the default value, ``mode="scale"`` multiplies the default value by ``1 + draw``.

    Example:
        >>> from torchtasks.envs.mujoco_declaration import Noise
        >>> Noise("normal", 0.1).scale, Noise("uniform", 0.05, mode="scale").mode
        (0.1, 'scale')
    """

    distribution: Literal["uniform", "normal"]
    scale: float
    mode: Literal["add", "scale"] = "add"

    def __post_init__(self) -> None:
        if self.distribution not in ("uniform", "normal"):
            raise ValueError(f"Noise distribution must be 'uniform' or 'normal', got {self.distribution!r}")
        scale = _finite(self.scale, "Noise scale")
        if scale < 0:
            raise ValueError(f"Noise scale must be >= 0, got {self.scale!r}")
        if self.mode not in ("add", "scale"):
            raise ValueError(f"Noise mode must be 'add' or 'scale', got {self.mode!r}")
        object.__setattr__(self, "scale", scale)

    def draw(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """``size`` draws from ``rng`` (Gymnasium's calls: ``uniform(-s, s, size)``, ``s * standard_normal(size)``)."""
        if self.distribution == "uniform":
            return rng.uniform(low=-self.scale, high=self.scale, size=size)
        return self.scale * rng.standard_normal(size)


@dataclass(frozen=True)
class FreeJointRanges:
    """Ranges drawn uniformly per env at a reset for a free joint (a floating base), added to its default state.

    Args:
        joint: the free joint's name; ``None``: the model's only free joint.
        position: ``(low, high)`` of x, y and z offsets in metres (three pairs); ``None``: none.
        yaw: ``(low, high)`` of a rotation about the world z axis in radians, applied to the default orientation.
        linear_velocity, angular_velocity: ``(low, high)`` of each of the three velocity coordinates (``qvel`` of
            the free joint: linear in the world frame, angular in the body frame).

    Example:
        >>> from torchtasks.envs.mujoco_declaration import FreeJointRanges
        >>> FreeJointRanges(position=((-0.5, 0.5), (-0.5, 0.5), (0.0, 0.0)), yaw=(-3.14, 3.14)).yaw
        (-3.14, 3.14)
    """

    joint: str | None = None
    position: tuple[tuple[float, float], ...] | None = None
    yaw: tuple[float, float] | None = None
    linear_velocity: tuple[tuple[float, float], ...] | None = None
    angular_velocity: tuple[tuple[float, float], ...] | None = None

    def __post_init__(self) -> None:
        for name in ("position", "linear_velocity", "angular_velocity"):
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 3:
                raise TypeError(f"FreeJointRanges {name} must be three (low, high) pairs (x, y, z), got {value!r}")
            object.__setattr__(
                self, name, tuple(_range(pair, f"FreeJointRanges {name}[{i}]") for i, pair in enumerate(value))
            )
        if self.yaw is not None:
            object.__setattr__(self, "yaw", _range(self.yaw, "FreeJointRanges yaw"))


@dataclass(frozen=True)
class Resets:
    """How a reset draws each env's initial state, from its own generator.

    The default state is ``qpos0`` and zero velocities (``mj_resetData``), or the keyframe named ``keyframe`` (its
    ``qpos``, ``qvel``, ``act``, ``ctrl``, mocap). Then, in this order, each env draws:

    - ``qpos_noise``, ``qvel_noise``: noise on every coordinate of ``qpos`` (quaternions included, unnormalised, as
      Gymnasium's resets) and of ``qvel``;
    - ``joint_noise``: ``{joint name: Noise}`` on a hinge or slide joint's position, in the order given;
    - ``free_joint``: :class:`FreeJointRanges` of a floating base;
    - ``steps``: :mod:`~torchtasks.envs.reset_steps`, in order (joints drawn in their ranges, random orientations,
      a target's position drawn per env, draws repeated until nothing touches, a few settling steps).

    Example:
        >>> from torchtasks.envs.mujoco_declaration import Noise, Resets
        >>> Resets(keyframe="home", joint_noise={"knee": Noise("uniform", 0.1)}).keyframe
        'home'
    """

    keyframe: str | None = None
    qpos_noise: Noise | None = None
    qvel_noise: Noise | None = None
    joint_noise: Mapping[str, Noise] = field(default_factory=dict)
    free_joint: FreeJointRanges | None = None
    steps: Sequence[ResetStep] = ()

    def __post_init__(self) -> None:
        if isinstance(self.steps, (str, bytes)) or not isinstance(self.steps, Sequence):
            raise TypeError(f"Resets steps must be a sequence of reset steps, got {self.steps!r}")
        for step in self.steps:
            if not isinstance(step, ResetStep):
                raise TypeError(
                    f"Resets steps must hold reset steps (torchtasks.envs.reset_steps), got {type(step).__name__}"
                )
        object.__setattr__(self, "steps", tuple(self.steps))
        for name in ("qpos_noise", "qvel_noise"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, Noise):
                raise TypeError(f"Resets {name} must be a Noise or None, got {value!r}")
        if not isinstance(self.joint_noise, Mapping) or not all(
            isinstance(k, str) and isinstance(v, Noise) for k, v in self.joint_noise.items()
        ):
            raise TypeError(f"Resets joint_noise must map joint names to Noise, got {self.joint_noise!r}")
        if self.free_joint is not None and not isinstance(self.free_joint, FreeJointRanges):
            raise TypeError(f"Resets free_joint must be a FreeJointRanges or None, got {self.free_joint!r}")
        if self.keyframe is not None and not isinstance(self.keyframe, str):
            raise TypeError(f"Resets keyframe must be a keyframe's name or None, got {self.keyframe!r}")


@dataclass(frozen=True)
class Actions:
    """How an action becomes the controls: ``ctrl = offset + scale * action`` per actuator.

    Args:
        scale: a positive factor, one for all actuators or one per actuator.
        offset: a value for all actuators, one per actuator, ``"qpos0"`` or a keyframe's name: the default position
            of each actuator's joint (position targets around a pose, as mjlab's ``JointPositionAction``; every
            actuator must drive a hinge or slide joint).

    With the defaults the action is the control (MuJoCo clamps it to ``ctrlrange``). The action spec is bounded by
    the actuators' control ranges mapped back through the affine map where all actuators are ``ctrllimited``, and
    unbounded otherwise.

    Example:
        >>> from torchtasks.envs.mujoco_declaration import Actions
        >>> Actions(scale=0.25, offset="home").offset
        'home'
    """

    scale: float | Sequence[float] = 1.0
    offset: float | Sequence[float] | str = 0.0


@dataclass(frozen=True, eq=False)
class ResolvedResets:
    """:class:`Resets` for one model: the keyframe id and each draw as ``(target, columns, noise)``."""

    keyframe: int
    #: ("qpos" | "qvel", column indices, Noise) in draw order
    noise: tuple[tuple[str, np.ndarray, Noise], ...]
    #: the free joint's qpos and qvel addresses and its ranges, or None
    free_joint: tuple[int, int, FreeJointRanges] | None
    #: the reset steps, in order (resolved in :attr:`MujocoDeclaration.reset_steps`)
    steps: tuple[ResetStep, ...] = ()


@dataclass(frozen=True, eq=False)
class MujocoDeclaration:
    """A batched MuJoCo env as data, resolved against its compiled model (built by :func:`declare`).

    Attributes:
        name: what messages and checkpoints call the env (a Gymnasium id or the model's label).
        model: the compiled model the batch simulates.
        frame_skip: MuJoCo substeps per env step.
        observation_readings: ``{entry key: readings concatenated}``; ``observation`` holds them resolved.
        state_readings: ``{entry key: readings concatenated}``, the task state; ``state`` holds them resolved.
        action_scale, action_offset: float64 ``[nu]``: ``ctrl = offset + scale * action``.
        action_low, action_high: the action spec's bounds (float64 ``[nu]``), or None: unbounded.
        resets: the resolved reset distribution.
        stage: ``"velocity"`` (readings of the returned state) or ``"step"`` (as ``mj_step`` leaves MjData).
        contact_forces: ``"forward"`` (``cfrc_ext`` of the last substep's forward pass) or ``"after_step"``
            (``mj_rnePostConstraint`` after the step, per env, as Gymnasium; a reset's are those ``mj_forward``
            leaves: none).
    """

    name: str
    model: mujoco.MjModel
    frame_skip: int
    observation_readings: Mapping[str, tuple[Reading, ...]]
    state_readings: Mapping[str, tuple[Reading, ...]]
    action_scale: np.ndarray
    action_offset: np.ndarray
    action_low: np.ndarray | None
    action_high: np.ndarray | None
    resets: ResolvedResets
    stage: Stage = "velocity"
    contact_forces: ContactForces = "forward"
    observation: Mapping[str, tuple[Resolved, ...]] = field(init=False, repr=False, compare=False)
    state: Mapping[str, tuple[Resolved, ...]] = field(init=False, repr=False, compare=False)
    #: ``resets.steps`` resolved: ``(step, function, the function of its model part or None)`` each
    reset_steps: tuple[tuple[ResetStep, Apply, Apply | None], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._resolve()

    def _resolve(self) -> None:
        # resolved readings and steps hold closures over the model's indices: rebuilt from them, never pickled
        object.__setattr__(self, "observation", _resolve(self.model, self.observation_readings))
        object.__setattr__(self, "state", _resolve(self.model, self.state_readings))
        steps = tuple(
            (step, step.resolve(self.model), step.resolve_model_part(self.model)) for step in self.resets.steps
        )
        object.__setattr__(self, "reset_steps", steps)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for name in ("observation", "state", "reset_steps"):
            state.pop(name, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._resolve()

    @property
    def dt(self) -> float:
        """The env's step in seconds: ``frame_skip * timestep``."""
        return float(self.model.opt.timestep) * self.frame_skip

    def entries(self) -> dict[str, tuple[Resolved, ...]]:
        """Every entry the env writes (observation then task state), by key."""
        return {**self.observation, **self.state}


# ---------------------------------------------------------------------------------------------- building
def _entries(value: object, argument: str, single_key: str | None) -> dict[str, tuple[Reading, ...]]:
    """``{key: readings}`` of an ``observation`` or ``state`` argument."""
    if value is None:
        return {}
    if isinstance(value, Reading) or (
        single_key is not None and isinstance(value, Sequence) and not isinstance(value, (str, bytes))
    ):
        value = {single_key: value}
    if not isinstance(value, Mapping):
        raise TypeError(
            f"{argument} must be a dict of entry names to readings"
            + (" (or one reading, or a list of readings)" if single_key else "")
            + f", got {type(value).__name__}"
        )
    entries: dict[str, tuple[Reading, ...]] = {}
    for key, readings in value.items():
        if not isinstance(key, str) or not key or key.startswith("_"):
            raise ValueError(f"{argument}: entry names must be non-empty strings not starting with '_', got {key!r}")
        parts = (readings,) if isinstance(readings, Reading) else readings
        if isinstance(parts, (str, bytes)) or not isinstance(parts, Sequence) or not parts:
            raise TypeError(f"{argument}[{key!r}] must be a reading or a non-empty list of readings, got {readings!r}")
        for part in parts:
            if not isinstance(part, Reading):
                raise TypeError(
                    f"{argument}[{key!r}] must hold readings (torchtasks.envs.readings), got {type(part).__name__}"
                )
        entries[key] = tuple(parts)
    return entries


def _per_actuator(value: object, nu: int, argument: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64) if not isinstance(value, str) else None
    if array is None or array.ndim > 1 or (array.ndim == 1 and array.shape != (nu,)):
        raise ValueError(f"{argument} must be a number or {nu} numbers (one per actuator), got {value!r}")
    if not np.isfinite(array).all():
        raise ValueError(f"{argument} must be finite, got {value!r}")
    return np.broadcast_to(array, (nu,)).copy()


def _default_pose(model: mujoco.MjModel, pose: str, argument: str) -> np.ndarray:
    """``qpos0`` or the ``qpos`` of the keyframe named ``pose``."""
    if pose == "qpos0":
        return np.array(model.qpos0)
    return np.array(model.key_qpos[object_id(model, "keyframe", pose, argument)])


def _resolve_actions(model: mujoco.MjModel, actions: Actions) -> tuple[np.ndarray, ...]:
    if not isinstance(actions, Actions):
        raise TypeError(f"actions must be an Actions or None, got {type(actions).__name__}")
    nu = int(model.nu)
    if nu == 0:
        raise ValueError(f"the model {model_label(model)} has no actuators, so an env of it cannot be controlled")
    scale = _per_actuator(actions.scale, nu, "actions scale")
    if not (scale > 0).all():
        raise ValueError(f"actions scale must be > 0 for every actuator, got {actions.scale!r}")
    if isinstance(actions.offset, str):
        pose = _default_pose(model, actions.offset, "actions offset")
        offset = np.empty(nu)
        for i in range(nu):
            joint = int(model.actuator_trnid[i, 0])
            if model.actuator_trntype[i] != mujoco.mjtTrn.mjTRN_JOINT or model.jnt_type[joint] not in (2, 3):
                raise ValueError(
                    f"actions offset={actions.offset!r} takes each actuator's joint position, but actuator "
                    f"{object_names(model, 'actuator')[i] or i!r} does not drive a hinge or slide joint"
                )
            offset[i] = pose[model.jnt_qposadr[joint]]
    else:
        offset = _per_actuator(actions.offset, nu, "actions offset")
    limited = np.asarray(model.actuator_ctrllimited, dtype=bool)
    if limited.all():
        ranges = np.asarray(model.actuator_ctrlrange, dtype=np.float64)
        low, high = (ranges[:, 0] - offset) / scale, (ranges[:, 1] - offset) / scale
    else:
        low = high = None
    return scale, offset, low, high


def _free_joint(model: mujoco.MjModel, name: str | None) -> int:
    free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    if name is None:
        if len(free) != 1:
            raise ValueError(
                f"Resets free_joint: the model has {len(free)} free joints; name the one to draw for"
                if free
                else "Resets free_joint: the model has no free joint (a floating base) to draw a position for"
            )
        return free[0]
    joint = object_id(model, "joint", name, "Resets free_joint joint")
    if model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"Resets free_joint: joint {name!r} is not a free joint")
    return joint


def _resolve_resets(model: mujoco.MjModel, resets: Resets) -> ResolvedResets:
    if not isinstance(resets, Resets):
        raise TypeError(f"resets must be a Resets or None, got {type(resets).__name__}")
    keyframe = -1 if resets.keyframe is None else object_id(model, "keyframe", resets.keyframe, "Resets keyframe")
    noise: list[tuple[str, np.ndarray, Noise]] = []
    if resets.qpos_noise is not None:
        noise.append(("qpos", np.arange(model.nq), resets.qpos_noise))
    if resets.qvel_noise is not None:
        noise.append(("qvel", np.arange(model.nv), resets.qvel_noise))
    for name, each in resets.joint_noise.items():
        joint = object_id(model, "joint", name, "Resets joint_noise")
        # ints on both sides: ``x in (enum, ...)`` compares enum == numpy int, which pybind11's enums answer False
        if int(model.jnt_type[joint]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ValueError(f"Resets joint_noise: joint {name!r} is not a hinge or slide joint (use free_joint)")
        noise.append(("qpos", np.array([model.jnt_qposadr[joint]]), each))
    free = None
    if resets.free_joint is not None:
        joint = _free_joint(model, resets.free_joint.joint)
        free = (int(model.jnt_qposadr[joint]), int(model.jnt_dofadr[joint]), resets.free_joint)
    return ResolvedResets(keyframe, tuple(noise), free, resets.steps)


def _control_steps(model: mujoco.MjModel, frame_skip: object, control_timestep: object) -> int:
    if frame_skip is not None and control_timestep is not None:
        raise ValueError(
            f"give frame_skip (substeps per step) or control_timestep (seconds per step), not both; got "
            f"frame_skip={frame_skip!r} and control_timestep={control_timestep!r}"
        )
    if control_timestep is None:
        if frame_skip is None:
            return 1
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, numbers.Integral) or frame_skip < 1:
            raise ValueError(f"frame_skip must be a positive int (substeps per step), got {frame_skip!r}")
        return int(frame_skip)
    step = _finite(control_timestep, "control_timestep")
    substeps = step / float(model.opt.timestep)
    if step <= 0 or abs(substeps - round(substeps)) > 1e-6 * max(1.0, substeps) or round(substeps) < 1:
        raise ValueError(
            f"control_timestep must be a positive multiple of the model's timestep {model.opt.timestep}, "
            f"got {control_timestep!r}"
        )
    return round(substeps)


def _resolve(model: mujoco.MjModel, entries: Mapping[str, tuple[Reading, ...]]) -> dict[str, tuple[Resolved, ...]]:
    return {key: tuple(reading.resolve(model) for reading in readings) for key, readings in entries.items()}


def _needs_contact_forces(resolved: Mapping[str, tuple[Resolved, ...]]) -> bool:
    def needs(part: Resolved) -> bool:
        return part.contact_forces or (part.difference_of is not None and needs(part.difference_of))

    return any(needs(part) for parts in resolved.values() for part in parts)


def _with_contact_force_sensor(source: object, model: mujoco.MjModel) -> mujoco.MjModel:
    """The model with a ``framelinacc`` sensor, whose evaluation in ``mj_forward`` fills ``cfrc_ext``."""
    if isinstance(source, mujoco.MjModel):
        raise ValueError(
            "a reading needs contact forces, which MuJoCo computes in a step only for a model with an accelerometer, "
            "force, torque, framelinacc or frameangacc sensor; this MjModel has none. Give the model as a file, an "
            "MJCF string or an MjSpec (the env then adds one), or add such a sensor to it"
        )
    spec = source.copy() if isinstance(source, mujoco.MjSpec) else None
    if spec is None:
        import os

        text = os.fspath(source)  # type: ignore[arg-type]
        spec = mujoco.MjSpec.from_string(text) if text.lstrip().startswith("<") else mujoco.MjSpec.from_file(text)
    sensor = spec.add_sensor()
    sensor.name = CONTACT_FORCE_SENSOR
    sensor.type = mujoco.mjtSensor.mjSENS_FRAMELINACC
    sensor.objtype = mujoco.mjtObj.mjOBJ_XBODY
    sensor.objname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, 0) or "world"
    return load_model(spec)


def declare(
    model: Any,
    *,
    observation: Reading | Sequence[Reading] | Mapping[str, Reading | Sequence[Reading]] | None = None,
    state: Mapping[str, Reading | Sequence[Reading]] | None = None,
    actions: Actions | None = None,
    resets: Resets | None = None,
    frame_skip: int | None = None,
    control_timestep: float | None = None,
    stage: Stage = "velocity",
) -> MujocoDeclaration:
    """Check and resolve a batched env's declaration against its model (see :class:`BatchedMujocoEnv`'s arguments).

    Example:
        >>> from torchtasks.envs import readings
        >>> from torchtasks.envs.mujoco_declaration import declare
        >>> xml = ('<mujoco><worldbody><body name="pole"><joint name="hinge"/>'
        ...        '<geom type="capsule" size="0.1" fromto="0 0 0 0 0 1"/></body></worldbody>'
        ...        '<actuator><motor joint="hinge" ctrlrange="-1 1"/></actuator></mujoco>')
        >>> declaration = declare(xml, observation=readings.joint_pos(), frame_skip=2)
        >>> declaration.frame_skip, list(declaration.observation), declaration.action_low
        (2, ['observation'], array([-1.]))
    """
    compiled = load_model(model)
    if stage not in ("velocity", "step"):
        raise ValueError(f"stage must be 'velocity' or 'step', got {stage!r}")
    observation_entries = _entries(observation, "observation", "observation")
    if not observation_entries:
        raise ValueError("observation must declare at least one reading (e.g. readings.joint_pos())")
    state_entries = _entries(state, "state", None)
    clash = sorted(set(observation_entries) & set(state_entries))
    if clash:
        raise ValueError(f"observation and state entries must have distinct names, both have {clash}")
    resolved = _resolve(compiled, {**observation_entries, **state_entries})
    if _needs_contact_forces(resolved) and not any(int(kind) in _RNE_POST_SENSORS for kind in compiled.sensor_type):
        compiled = _with_contact_force_sensor(model, compiled)
    scale, offset, low, high = _resolve_actions(compiled, Actions() if actions is None else actions)
    return MujocoDeclaration(
        name=model_label(model),
        model=compiled,
        frame_skip=_control_steps(compiled, frame_skip, control_timestep),
        observation_readings=observation_entries,
        state_readings=state_entries,
        action_scale=scale,
        action_offset=offset,
        action_low=low,
        action_high=high,
        resets=_resolve_resets(compiled, Resets() if resets is None else resets),
        stage=stage,
    )


del _readings
