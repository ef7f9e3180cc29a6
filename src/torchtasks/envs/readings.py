"""The reading kinds of the batched MuJoCo env: named model quantities, computed for every env at once.

A reading (``joint_pos("knee")``, ``body_lin_vel("torso", frame="local")``, ``sensor("gyro")``, ...) is a frozen,
picklable declaration. ``reading.resolve(model)`` checks its names against the model (the closest names on a miss)
and returns a :class:`Resolved`: the bound ``mujoco.batch.Batch`` arrays it reads and a ``compute`` from those
``(num_envs, ...)`` arrays to a new ``(num_envs, *shape)`` array, written with indexing and arithmetic that run on
numpy arrays and torch tensors alike. ``difference``, ``elementwise`` and ``norm`` compute a value from other
readings. :data:`READING_KINDS` lists every kind.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from torchtasks._did_you_mean import did_you_mean
from torchtasks._optional import missing_extra

try:
    import mujoco
    import mujoco.batch
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.readings", _error) from _error

from torchtasks.envs.mujoco_model import object_id, object_names

__all__ = [
    "READING_KINDS",
    "ActuatorCtrl",
    "ActuatorForce",
    "BodyAngVel",
    "BodyLinVel",
    "BodyPos",
    "BodyQuat",
    "ContactForce",
    "DataField",
    "Difference",
    "Elementwise",
    "FiniteDifference",
    "GeomPos",
    "JointPos",
    "JointVel",
    "LastAction",
    "MassCentre",
    "Norm",
    "ProjectedGravity",
    "Reading",
    "Resolved",
    "Sensor",
    "SitePos",
    "SiteQuat",
    "SubtreeCom",
    "SubtreeLinVel",
    "Time",
    "actuator_ctrl",
    "actuator_force",
    "body_ang_vel",
    "body_lin_vel",
    "body_pos",
    "body_quat",
    "contact_force",
    "data_field",
    "difference",
    "elementwise",
    "finite_difference",
    "geom_pos",
    "joint_pos",
    "joint_vel",
    "last_action",
    "mass_centre",
    "norm",
    "projected_gravity",
    "sensor",
    "site_pos",
    "site_quat",
    "subtree_com",
    "subtree_lin_vel",
    "time",
]

#: a bound array: a numpy array today, a torch tensor of another backend later
Array = Any

#: MuJoCo's smallest value (``mjMINVAL``), the floor of a subtree mass it divides by
_MINVAL = 1e-15

_XYZ = np.arange(3)
_WXYZ = np.arange(4)
_ANGULAR = np.arange(3)  # cvel = (angular, linear)
_LINEAR = np.arange(3, 6)
_YZX = np.array([1, 2, 0])
_ZXY = np.array([2, 0, 1])

_FRAMES = ("world", "local")
_POINTS = ("origin", "com")


@dataclass(frozen=True)
class Resolved:
    """A reading resolved against one model: what it reads and how it computes its value for every env.

    Attributes:
        label: the reading as written, e.g. ``"joint_pos(knee, hip)"``.
        shape: the value's shape per env.
        fields: the ``MjData`` fields it reads, as ``mujoco.batch.Batch.bind`` names.
        model_fields: the ``MjModel`` fields it reads per env (``"body_mass"``, ``"opt.gravity"``); ``compute``
            finds them under ``"model.<field>"``.
        contact_forces: whether it needs ``cfrc_ext`` filled (``mj_rnePostConstraint``).
        action: whether it reads the last action (``"action"``, ``(n, nu)``, zeros after a reset).
        difference_of: for a finite difference, the reading whose change over a step it is (the caller keeps its
            previous value; ``compute`` then raises); else ``None``.
        compute: the bound arrays (a mapping of the names above to ``(n, ...)`` arrays) to a new ``(n, *shape)``
            array, clipped when the reading has ``clip``.
        labels: a name per element of the flattened value, e.g. ``("torso.x", "torso.y", "torso.z")``.
        dt: for a finite difference, the time it divides by (``None``: the env's control timestep).

    Example:
        >>> import numpy as np
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> model = load_model('<mujoco><worldbody><body name="arm"><joint name="hinge"/><geom size=".1"/>'
        ...                    '</body></worldbody></mujoco>')
        >>> resolved = joint_pos("hinge").resolve(model)
        >>> resolved.label, resolved.shape, resolved.fields, resolved.labels
        ('joint_pos(hinge)', (1,), ('qpos',), ('hinge',))
        >>> resolved.compute({"qpos": np.array([[0.5], [-0.25]])})
        array([[ 0.5 ],
               [-0.25]])
    """

    label: str
    shape: tuple[int, ...]
    fields: tuple[str, ...]
    model_fields: tuple[str, ...]
    contact_forces: bool
    action: bool
    difference_of: Resolved | None
    compute: Callable[[Mapping[str, Array]], Array]
    labels: tuple[str, ...] = ()
    dt: float | None = None


# ----------------------------------------------------------------------------------------------------- arithmetic
# Each works on numpy arrays and torch tensors alike: integer-array indexing (a copy in both), + - * /, ``.sum(axis=)``,
# ``.reshape``, ``.clip``, slice assignment and the functions of ``_unary``.


def _unary(name: str, value: Array) -> Array:
    """numpy's function ``name`` (``"log1p"``, ``"sin"``, ...) of a numpy array, the tensor method of that name of a
    tensor (torch's own implementation: it may differ from numpy's in the last bit)."""
    return getattr(np, name)(value) if isinstance(value, np.ndarray) else getattr(value, name)()


def _length(value: Array) -> Array:
    """The Euclidean norm of each row of ``(n, k)`` values: ``(n,)``, for 3-vectors as ``mju_norm3`` (on numpy)."""
    return (value * value).sum(axis=1) ** 0.5


def _cross(a: Array, b: Array) -> Array:
    """``a x b`` over the last axis, in ``mju_cross``'s order of operations."""
    return a[..., _YZX] * b[..., _ZXY] - a[..., _ZXY] * b[..., _YZX]


def _rotate_transposed(mat: Array, vec: Array) -> Array:
    """``mat^T vec`` for row-major ``(..., 9)`` matrices, in ``mju_mulMatTVec3``'s order of operations."""
    return mat[..., 0:3] * vec[..., 0:1] + mat[..., 3:6] * vec[..., 1:2] + mat[..., 6:9] * vec[..., 2:3]


def _gather(arrays: Mapping[str, Array], *, name: str, index: np.ndarray) -> Array:
    return arrays[name][:, index]


def _gather_row(arrays: Mapping[str, Array], *, name: str, row: int, index: np.ndarray) -> Array:
    return arrays[name][:, row, index]


def _gather_rows(arrays: Mapping[str, Array], *, name: str, rows: np.ndarray) -> Array:
    values = arrays[name][:, rows]
    return values.reshape(values.shape[0], -1)


def _contact_rows(arrays: Mapping[str, Array], *, rows: np.ndarray, roots: np.ndarray) -> Array:
    """``cfrc_ext`` of ``rows`` without what ``xfrc_applied`` put there: MuJoCo adds each body's applied
    ``(force, torque)`` at its centre of mass ``xipos`` as ``(torque + (xipos - c) x force, force)`` about the
    centre of mass ``c`` of the body's tree (``subtree_com`` of its root, ``roots``)."""
    external = arrays["cfrc_ext"][:, rows]
    applied = arrays["xfrc_applied"][:, rows]
    if not applied.any():  # nothing applied (the common step): cfrc_ext is the contacts
        return external.reshape(external.shape[0], -1)
    force, torque = applied[..., :3], applied[..., 3:]
    arm = arrays["xipos"][:, rows] - arrays["subtree_com"][:, roots]
    contacts = np.concatenate([external[..., :3] - torque - np.cross(arm, force), external[..., 3:] - force], -1)
    return contacts.reshape(contacts.shape[0], -1)


def _relative(arrays: Mapping[str, Array], *, index: np.ndarray, reference: str, key: int | None) -> Array:
    default = arrays[reference][:, index] if key is None else arrays[reference][:, key, index]
    return arrays["qpos"][:, index] - default


def _point_velocity(cvel: Array, point: Array, centre: Array) -> Array:
    """The linear velocity of a world point moving with a body of com-based velocity ``cvel`` about ``centre``."""
    return cvel[..., _LINEAR] - _cross(point - centre, cvel[..., _ANGULAR])


def _body_velocity(
    arrays: Mapping[str, Array], *, body: int, root: int, position: str, rotation: str | None, linear: bool
) -> Array:
    if linear:
        value = _point_velocity(arrays["cvel"][:, body], arrays[position][:, body], arrays["subtree_com"][:, root])
    else:
        value = arrays["cvel"][:, body, _ANGULAR]
    return value if rotation is None else _rotate_transposed(arrays[rotation][:, body], value)


def _projected_gravity(arrays: Mapping[str, Array], *, body: int) -> Array:
    gravity = arrays["model.opt.gravity"]
    return _rotate_transposed(arrays["xmat"][:, body], gravity * (1 / _length(gravity)[:, None]))


def _subtree_lin_vel(
    arrays: Mapping[str, Array],
    *,
    body: int,
    bodies: np.ndarray,
    roots: np.ndarray,
    merges: tuple[tuple[int, int], ...],
) -> Array:
    # mj_subtreeVel: each body's com velocity times its mass, summed child into parent from the last body back, times
    # 1 / max(mjMINVAL, subtree mass); ``bodies`` is the subtree in id order, ``merges`` (child, parent) positions
    velocity = _point_velocity(arrays["cvel"][:, bodies], arrays["xipos"][:, bodies], arrays["subtree_com"][:, roots])
    momentum = velocity * arrays["model.body_mass"][:, bodies, None]
    sums = [momentum[:, i] for i in range(len(bodies))]
    for child, parent in merges:
        sums[parent] = sums[parent] + sums[child]
    scale = 1 / arrays["model.body_subtreemass"][:, body].clip(_MINVAL, None)
    return sums[0] * scale[:, None]


def _mass_centre(arrays: Mapping[str, Array]) -> Array:
    mass = arrays["model.body_mass"]
    return (mass[:, :, None] * arrays["xipos"]).sum(axis=1) / mass.sum(axis=1)[:, None]


def _time(arrays: Mapping[str, Array]) -> Array:
    return arrays["time"].reshape(-1, 1) * 1


def _difference(
    arrays: Mapping[str, Array],
    *,
    first: Callable[[Mapping[str, Array]], Array],
    second: Callable[[Mapping[str, Array]], Array],
    rotation: str | None,
    row: int,
) -> Array:
    # in a frame: R^T (a - b), i.e. dm_control's ``(a - b) @ R`` in mju_mulMatTVec3's order of operations
    value = first(arrays) - second(arrays)
    return value if rotation is None else _rotate_transposed(arrays[rotation][:, row], value)


def _elementwise(
    arrays: Mapping[str, Array],
    *,
    inner: Callable[[Mapping[str, Array]], Array],
    function: Callable[[Array], Array],
) -> Array:
    return function(inner(arrays))


def _norm(arrays: Mapping[str, Array], *, inner: Callable[[Mapping[str, Array]], Array], offset: float) -> Array:
    return _length(inner(arrays))[:, None] + offset


def _selected(
    arrays: Mapping[str, Array],
    *,
    inner: Callable[[Mapping[str, Array]], Array],
    index: np.ndarray | None,
    clip: tuple[float, float] | None,
) -> Array:
    value = inner(arrays)
    if index is not None:
        value = value[:, index]
    return value if clip is None else value.clip(clip[0], clip[1])


def _differenced_by_the_engine(arrays: Mapping[str, Array], *, label: str) -> Array:
    raise RuntimeError(
        f"{label} is the change of its reading over a step: the env keeps the reading's previous value and "
        f"differences it (Resolved.difference_of); it has no compute of its own"
    )


# ------------------------------------------------------------------------------------------ elementwise functions


def _log1p(value: Array) -> Array:
    return _unary("log1p", value)


def _arcsinh(value: Array) -> Array:
    return _unary("arcsinh", value)


def _sin_cos(value: Array) -> Array:
    interleaved = value[:, np.repeat(np.arange(value.shape[1]), 2)]  # a new (n, 2k) array of the input's type
    interleaved[:, 0::2] = _unary("sin", value)
    interleaved[:, 1::2] = _unary("cos", value)
    return interleaved


@dataclass(frozen=True)
class _Function:
    """An elementwise function of :func:`elementwise`: ``(n, k)`` values to ``(n, k * len(labels))``."""

    compute: Callable[[Array], Array]
    #: the label formats of the entries one element ``x`` gives, in their order
    labels: tuple[str, ...]


#: the functions of :func:`elementwise`: name -> its computation and the labels of its entries
_FUNCTIONS: dict[str, _Function] = {
    "log1p": _Function(_log1p, ("log1p({})",)),
    "arcsinh": _Function(_arcsinh, ("arcsinh({})",)),
    "sin_cos": _Function(_sin_cos, ("sin({})", "cos({})")),
}

#: the kinds of object a difference can be expressed in the frame of -> the MjData field of their rotation matrices
_FRAME_ROTATIONS = {"body": "xmat", "geom": "geom_xmat", "site": "site_xmat"}


# --------------------------------------------------------------------------------------------------------- checks


def _check_name(value: object, argument: str, what: str) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{argument} must be the name of a {what} (a string), got {value!r}")
    if not value:
        raise ValueError(f"{argument} must be the name of a {what}, got the empty string")
    return value


def _check_names(values: object, argument: str, what: str) -> tuple[str, ...]:
    if isinstance(values, str) or not isinstance(values, Sequence):
        raise TypeError(f"{argument} must be a sequence of {what} names, got {values!r}")
    names = tuple(_check_name(value, argument, what) for value in values)
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ValueError(f"{argument} names each {what} once, got {', '.join(map(repr, twice))} more than once")
    return names


def _check_choice(value: object, argument: str, choices: Sequence[str]) -> str:
    if value not in choices:
        raise ValueError(f"{argument} must be one of {list(choices)}, got {value!r}")
    return value  # type: ignore[return-value]


def _check_clip(clip: object) -> tuple[float, float] | None:
    if clip is None:
        return None
    if isinstance(clip, (str, bytes)) or not isinstance(clip, Sequence) or len(clip) != 2:
        raise TypeError(f"clip must be None or a pair (low, high) of numbers, got {clip!r}")
    for bound in clip:
        if isinstance(bound, bool) or not isinstance(bound, (int, float, np.integer, np.floating)):
            raise TypeError(f"clip must be a pair (low, high) of numbers, got {clip!r}")
    low, high = (float(bound) for bound in clip)
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"clip must be finite numbers (low, high), got {clip!r}")
    if low > high:
        raise ValueError(f"clip must be (low, high) with low <= high, got {clip!r}")
    return low, high


def _check_index(index: object) -> tuple[int, ...] | None:
    if index is None:
        return None
    if isinstance(index, (int, np.integer)) and not isinstance(index, bool):
        index = (index,)  # one element: body_pos("torso", index=2) is the height
    if isinstance(index, (str, bytes)) or not isinstance(index, Sequence):
        raise TypeError(f"index must be None, an int or a sequence of element positions (ints), got {index!r}")
    for position in index:
        if isinstance(position, bool) or not isinstance(position, (int, np.integer)):
            raise TypeError(f"index must be a sequence of element positions (ints), got {index!r}")
    if not index:
        raise ValueError("index must select at least one element, got an empty sequence")
    return tuple(int(position) for position in index)


def _check_reading(value: object, argument: str) -> Reading:
    """An input of a composite reading: any reading but a finite difference (which the env computes from the value
    its reading had before the step, so only as an entry's outermost reading)."""
    if not isinstance(value, Reading):
        raise TypeError(f"{argument} must be a reading (e.g. body_pos('torso')), got {value!r}")
    if isinstance(value, FiniteDifference):
        raise ValueError(
            f"{argument} must not be a finite difference (the env differences a whole entry's reading, so a finite "
            f"difference can only be outermost: finite_difference(...) of the composite), got {value._label()}"
        )
    return value


def _check_frame(frame: object, argument: str) -> str | None:
    if frame is None:
        return None
    forms = [f"'{kind}:<name>'" for kind in _FRAME_ROTATIONS]
    forms_text = f"{', '.join(forms[:-1])} or {forms[-1]}"
    if not isinstance(frame, str):
        raise TypeError(f"{argument} must be None or a string {forms_text}, got {frame!r}")
    kind, colon, name = frame.partition(":")
    if not colon or not name:
        raise ValueError(f"{argument} must be None or {forms_text} (the object whose frame it is), got {frame!r}")
    if kind not in _FRAME_ROTATIONS:
        raise ValueError(
            f"{argument} must be {forms_text}: the kind {kind!r} of {frame!r} is none of {list(_FRAME_ROTATIONS)}"
            f"{did_you_mean(kind, list(_FRAME_ROTATIONS))}"
        )
    return frame


def _check_number(value: object, argument: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{argument} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{argument} must be a finite number, got {value!r}")
    return float(value)


def _check_model(model: object) -> mujoco.MjModel:
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(
            f"resolve takes a compiled mujoco.MjModel (torchtasks.envs.mujoco_model.load_model makes one), "
            f"got {type(model).__name__}"
        )
    return model


def _axes(name: str, suffixes: Sequence[str]) -> tuple[str, ...]:
    return tuple(f"{name}.{suffix}" for suffix in suffixes)


_JOINT_QPOS = {
    int(mujoco.mjtJoint.mjJNT_FREE): ("x", "y", "z", "qw", "qx", "qy", "qz"),
    int(mujoco.mjtJoint.mjJNT_BALL): ("qw", "qx", "qy", "qz"),
}
_JOINT_QVEL = {
    int(mujoco.mjtJoint.mjJNT_FREE): ("vx", "vy", "vz", "wx", "wy", "wz"),
    int(mujoco.mjtJoint.mjJNT_BALL): ("wx", "wy", "wz"),
}
_JOINT_TYPE_NAMES = {int(kind): name[len("mjJNT_") :].lower() for name, kind in mujoco.mjtJoint.__members__.items()}


def _element_labels(name: str, suffixes: tuple[str, ...] | None) -> tuple[str, ...]:
    return (name,) if suffixes is None else _axes(name, suffixes)


# -------------------------------------------------------------------------------------------------------- readings


@dataclass(frozen=True)
class Reading:
    """A named model quantity of the batched MuJoCo env; the kinds below derive from it.

    Every kind takes ``index``, the positions of the elements to keep (e.g. ``(2,)``: a position's height), and
    ``clip=(low, high)``: finite numbers with ``low <= high``, applied to the value by ``compute``.
    ``resolve(model)`` checks the reading against a compiled ``mujoco.MjModel`` and returns its :class:`Resolved`.

    Example:
        >>> from torchtasks.envs.readings import Reading, joint_vel
        >>> isinstance(joint_vel(clip=(-10, 10)), Reading), joint_vel(clip=(-10, 10)).clip
        (True, (-10.0, 10.0))
    """

    kind: ClassVar[str] = ""
    index: tuple[int, ...] | None = field(default=None, kw_only=True)
    clip: tuple[float, float] | None = field(default=None, kw_only=True)

    def __post_init__(self) -> None:
        object.__setattr__(self, "index", _check_index(self.index))
        object.__setattr__(self, "clip", _check_clip(self.clip))

    def resolve(self, model: mujoco.MjModel) -> Resolved:
        """This reading against ``model``: its shape, the arrays it reads and its ``compute``."""
        resolved = self._resolve(_check_model(model))
        if self.index is None and self.clip is None:
            return resolved
        size = int(np.prod(resolved.shape, dtype=np.int64))
        outside = [position for position in self.index or () if not 0 <= position < size]
        if outside:
            raise ValueError(
                f"{self._label()}: index must be positions in [0, {size}) of its {size} elements, got {self.index}"
            )
        index = None if self.index is None else np.array(self.index, dtype=np.int64)
        selected = resolved.labels if index is None else tuple(resolved.labels[i] for i in self.index)  # type: ignore[union-attr]
        return dataclasses.replace(
            resolved,
            label=self._label(),
            shape=resolved.shape if index is None else (len(index),),
            labels=selected,
            compute=functools.partial(_selected, inner=resolved.compute, index=index, clip=self.clip),
        )

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        raise NotImplementedError(f"{type(self).__name__} must define _resolve")

    def _arguments(self) -> list[str]:
        return []

    def _label(self) -> str:
        arguments = self._arguments()
        if self.index is not None:
            arguments.append(f"index={self.index}")
        if self.clip is not None:
            arguments.append(f"clip=({self.clip[0]:g}, {self.clip[1]:g})")
        return f"{self.kind}({', '.join(arguments)})"

    def _resolved(
        self,
        shape: tuple[int, ...],
        fields: tuple[str, ...],
        compute: Callable[[Mapping[str, Array]], Array],
        labels: tuple[str, ...],
        *,
        model_fields: tuple[str, ...] = (),
        contact_forces: bool = False,
        action: bool = False,
    ) -> Resolved:
        return Resolved(
            label=self._label(),
            shape=shape,
            fields=fields,
            model_fields=model_fields,
            contact_forces=contact_forces,
            action=action,
            difference_of=None,
            compute=compute,
            labels=labels,
        )


def _joints(model: mujoco.MjModel, joints: tuple[str, ...], argument: str) -> list[int]:
    if joints:
        return [object_id(model, "joint", name, argument) for name in joints]
    return list(range(model.njnt))


def _joint_name(model: mujoco.MjModel, joint: int) -> str:
    return object_names(model, "joint")[joint] or f"joint{joint}"


@dataclass(frozen=True)
class JointPos(Reading):
    """Joint positions (``qpos`` entries): shape ``(sum of sizes,)``, a free joint 7 (world position, then the
    orientation quaternion w, x, y, z), a ball joint 4 (quaternion), a hinge or slide 1; all joints when none named.

    ``relative_to`` subtracts a default pose from hinge and slide joints: ``"qpos0"`` (the model's reference pose,
    per env) or the name of a keyframe; a free or ball joint is refused there (a quaternion has no difference).

    Example:
        >>> import numpy as np
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import joint_pos
        >>> model = load_model('<mujoco><worldbody><body name="arm"><joint name="hinge" ref="0.5"/><geom size=".1"/>'
        ...                    '</body></worldbody></mujoco>')
        >>> resolved = joint_pos("hinge", relative_to="qpos0").resolve(model)
        >>> resolved.label, resolved.fields, resolved.model_fields
        ('joint_pos(hinge, relative_to=qpos0)', ('qpos',), ('qpos0',))
        >>> resolved.compute({"qpos": np.array([[0.75]]), "model.qpos0": np.array([[0.5]])})
        array([[0.25]])
    """

    kind: ClassVar[str] = "joint_pos"
    joints: tuple[str, ...] = ()
    relative_to: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "joints", _check_names(self.joints, "joint_pos joints", "joint"))
        if self.relative_to is not None:
            _check_name(self.relative_to, "joint_pos relative_to", "keyframe (or 'qpos0')")

    def _arguments(self) -> list[str]:
        return [*self.joints, *([] if self.relative_to is None else [f"relative_to={self.relative_to}"])]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        joints = _joints(model, self.joints, "joint_pos joints")
        index: list[int] = []
        labels: list[str] = []
        for joint in joints:
            kind = int(model.jnt_type[joint])
            suffixes = _JOINT_QPOS.get(kind)
            if self.relative_to is not None and suffixes is not None:
                raise ValueError(
                    f"joint_pos relative_to: joint {_joint_name(model, joint)!r} is a {_JOINT_TYPE_NAMES[kind]} joint; "
                    f"only hinge and slide joints have a position relative to a default pose "
                    f"(name the hinge and slide joints, or drop relative_to)"
                )
            start = int(model.jnt_qposadr[joint])
            size = 1 if suffixes is None else len(suffixes)
            index.extend(range(start, start + size))
            labels.extend(_element_labels(_joint_name(model, joint), suffixes))
        positions = np.array(index, dtype=np.int64)
        if self.relative_to is None:
            compute = functools.partial(_gather, name="qpos", index=positions)
            return self._resolved((len(index),), ("qpos",), compute, tuple(labels))
        if self.relative_to == "qpos0":
            reference, key = "qpos0", None
        else:
            reference, key = "key_qpos", object_id(model, "keyframe", self.relative_to, "joint_pos relative_to")
        compute = functools.partial(_relative, index=positions, reference="model." + reference, key=key)
        return self._resolved((len(index),), ("qpos",), compute, tuple(labels), model_fields=(reference,))


@dataclass(frozen=True)
class JointVel(Reading):
    """Joint velocities (``qvel`` entries): shape ``(sum of sizes,)``, a free joint 6 (linear velocity in the world
    frame, then angular velocity in the body frame, as MuJoCo's ``qvel``), a ball joint 3, a hinge or slide 1; all
    joints when none named.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import joint_vel
        >>> model = load_model('<mujoco><worldbody><body name="ball"><freejoint name="root"/><geom size=".1"/>'
        ...                    '</body></worldbody></mujoco>')
        >>> resolved = joint_vel("root").resolve(model)
        >>> resolved.shape, resolved.labels[:2]
        ((6,), ('root.vx', 'root.vy'))
    """

    kind: ClassVar[str] = "joint_vel"
    joints: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "joints", _check_names(self.joints, "joint_vel joints", "joint"))

    def _arguments(self) -> list[str]:
        return list(self.joints)

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        index: list[int] = []
        labels: list[str] = []
        for joint in _joints(model, self.joints, "joint_vel joints"):
            suffixes = _JOINT_QVEL.get(int(model.jnt_type[joint]))
            start = int(model.jnt_dofadr[joint])
            index.extend(range(start, start + (1 if suffixes is None else len(suffixes))))
            labels.extend(_element_labels(_joint_name(model, joint), suffixes))
        compute = functools.partial(_gather, name="qvel", index=np.array(index, dtype=np.int64))
        return self._resolved((len(index),), ("qvel",), compute, tuple(labels))


def _actuators(model: mujoco.MjModel, actuators: tuple[str, ...], argument: str) -> tuple[np.ndarray, tuple[str, ...]]:
    ids = [object_id(model, "actuator", name, argument) for name in actuators] if actuators else list(range(model.nu))
    names = object_names(model, "actuator")
    return np.array(ids, dtype=np.int64), tuple(names[each] or f"actuator{each}" for each in ids)


@dataclass(frozen=True)
class ActuatorCtrl(Reading):
    """Actuator controls (``ctrl`` entries, as written, before MuJoCo clamps them to ``ctrlrange``): shape
    ``(number of actuators,)``; all actuators when none named.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import actuator_ctrl
        >>> model = load_model('<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody>'
        ...                    '<actuator><motor name="m" joint="j"/></actuator></mujoco>')
        >>> actuator_ctrl().resolve(model).labels
        ('m',)
    """

    kind: ClassVar[str] = "actuator_ctrl"
    _field: ClassVar[str] = "ctrl"
    actuators: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "actuators", _check_names(self.actuators, f"{self.kind} actuators", "actuator"))

    def _arguments(self) -> list[str]:
        return list(self.actuators)

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        ids, labels = _actuators(model, self.actuators, f"{self.kind} actuators")
        compute = functools.partial(_gather, name=self._field, index=ids)
        return self._resolved((len(ids),), (self._field,), compute, labels)


@dataclass(frozen=True)
class ActuatorForce(ActuatorCtrl):
    """Actuator forces (``actuator_force`` entries, the scalar force of each actuator's transmission): shape
    ``(number of actuators,)``; all actuators when none named.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import actuator_force
        >>> model = load_model('<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody>'
        ...                    '<actuator><motor name="m" joint="j"/></actuator></mujoco>')
        >>> actuator_force("m").resolve(model).fields
        ('actuator_force',)
    """

    kind: ClassVar[str] = "actuator_force"
    _field: ClassVar[str] = "actuator_force"


@dataclass(frozen=True)
class Sensor(Reading):
    """A sensor's data (``sensordata[adr:adr + dim]``) of any sensor type, in the sensor's own frame and units:
    shape ``(dim,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import sensor
        >>> model = load_model('<mujoco><worldbody><body><freejoint/><geom size=".1"/><site name="imu"/></body>'
        ...                    '</worldbody><sensor><gyro name="gyro" site="imu"/></sensor></mujoco>')
        >>> resolved = sensor("gyro").resolve(model)
        >>> resolved.shape, resolved.labels
        ((3,), ('gyro[0]', 'gyro[1]', 'gyro[2]'))
    """

    kind: ClassVar[str] = "sensor"
    name: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_name(self.name, "sensor name", "sensor")

    def _arguments(self) -> list[str]:
        return [self.name]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        sensor_id = object_id(model, "sensor", self.name, "sensor name")
        start, dim = int(model.sensor_adr[sensor_id]), int(model.sensor_dim[sensor_id])
        compute = functools.partial(_gather, name="sensordata", index=np.arange(start, start + dim))
        labels = (self.name,) if dim == 1 else tuple(f"{self.name}[{i}]" for i in range(dim))
        return self._resolved((dim,), ("sensordata",), compute, labels)


@dataclass(frozen=True)
class _BodyReading(Reading):
    body: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_name(self.body, f"{self.kind} body", "body")

    def _arguments(self) -> list[str]:
        return [self.body]

    def _body(self, model: mujoco.MjModel) -> int:
        return object_id(model, "body", self.body, f"{self.kind} body")


@dataclass(frozen=True)
class BodyPos(_BodyReading):
    """A body's position in the world frame: its frame's origin (``xpos`` row, ``point="origin"``) or its centre of
    mass (``xipos`` row, ``point="com"``): shape ``(3,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_pos
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> body_pos("torso").resolve(model).labels
        ('torso.x', 'torso.y', 'torso.z')
        >>> height = body_pos("torso", index=(2,)).resolve(model)
        >>> height.label, height.shape, height.labels
        ('body_pos(torso, index=(2,))', (1,), ('torso.z',))
        >>> body_pos("torso", point="com").resolve(model).fields
        ('xipos',)
    """

    kind: ClassVar[str] = "body_pos"
    point: str = "origin"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_choice(self.point, f"{self.kind} point", _POINTS)

    def _arguments(self) -> list[str]:
        return [self.body, *([] if self.point == "origin" else [f"point={self.point}"])]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        name = "xpos" if self.point == "origin" else "xipos"
        compute = functools.partial(_gather_row, name=name, row=self._body(model), index=_XYZ)
        return self._resolved((3,), (name,), compute, _axes(self.body, "xyz"))


@dataclass(frozen=True)
class BodyQuat(_BodyReading):
    """A body frame's orientation in the world frame (``xquat`` row, w, x, y, z): shape ``(4,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_quat
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> body_quat("torso").resolve(model).shape
        (4,)
    """

    kind: ClassVar[str] = "body_quat"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        compute = functools.partial(_gather_row, name="xquat", row=self._body(model), index=_WXYZ)
        return self._resolved((4,), ("xquat",), compute, _axes(self.body, ("qw", "qx", "qy", "qz")))


@dataclass(frozen=True)
class BodyLinVel(_BodyReading):
    """A body's linear velocity: shape ``(3,)``, equal to ``mj_objectVelocity``'s linear part.

    ``point="origin"`` is the velocity of the body frame's origin (``mjOBJ_XBODY``), ``"com"`` of the body's centre
    of mass (``mjOBJ_BODY``). ``frame="world"`` gives it in world axes, ``"local"`` in the body's own (``flg_local``):
    the body frame (``xmat``) for the origin, the inertia frame (``ximat``) for the centre of mass.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_lin_vel
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = body_lin_vel("torso", frame="local").resolve(model)
        >>> resolved.label, resolved.fields
        ('body_lin_vel(torso, frame=local)', ('cvel', 'subtree_com', 'xpos', 'xmat'))
    """

    kind: ClassVar[str] = "body_lin_vel"
    _linear: ClassVar[bool] = True
    frame: str = "world"
    point: str = "origin"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_choice(self.frame, f"{self.kind} frame", _FRAMES)
        _check_choice(self.point, f"{self.kind} point", _POINTS)

    def _arguments(self) -> list[str]:
        arguments = [self.body]
        if self.frame != "world":
            arguments.append(f"frame={self.frame}")
        if self.point != "origin":
            arguments.append(f"point={self.point}")
        return arguments

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        body = self._body(model)
        position, rotation = ("xpos", "xmat") if self.point == "origin" else ("xipos", "ximat")
        local = rotation if self.frame == "local" else None
        compute = functools.partial(
            _body_velocity,
            body=body,
            root=int(model.body_rootid[body]),
            position=position,
            rotation=local,
            linear=self._linear,
        )
        fields = ("cvel", "subtree_com", position) if self._linear else ("cvel",)
        fields += () if local is None else (local,)
        suffixes = ("vx", "vy", "vz") if self._linear else ("wx", "wy", "wz")
        return self._resolved((3,), fields, compute, _axes(self.body, suffixes))


@dataclass(frozen=True)
class BodyAngVel(BodyLinVel):
    """A body's angular velocity: shape ``(3,)``, equal to ``mj_objectVelocity``'s angular part.

    ``frame="world"`` gives it in world axes, ``"local"`` in the body's own: the body frame (``xmat``) with
    ``point="origin"`` (``mjOBJ_XBODY``), the inertia frame (``ximat``) with ``point="com"`` (``mjOBJ_BODY``); the
    point changes nothing else.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_ang_vel
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> body_ang_vel("torso", frame="local").resolve(model).fields
        ('cvel', 'xmat')
    """

    kind: ClassVar[str] = "body_ang_vel"
    _linear: ClassVar[bool] = False


@dataclass(frozen=True)
class ProjectedGravity(_BodyReading):
    """The direction of gravity in a body's frame: shape ``(3,)``, ``xmat^T g / |g|`` with the env's own gravity
    (``opt.gravity``, per env); ``(0, 0, -1)`` for an upright body under the usual gravity. A model whose gravity is
    zero or disabled is refused (an env whose gravity is set to zero later reads NaN).

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import projected_gravity
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> projected_gravity("torso").resolve(model).model_fields
        ('opt.gravity',)
    """

    kind: ClassVar[str] = "projected_gravity"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        body = self._body(model)
        disabled = model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
        if disabled or not np.any(model.opt.gravity):
            reason = "disables gravity" if disabled else f"has zero gravity (opt.gravity {list(model.opt.gravity)})"
            raise ValueError(f"projected_gravity({self.body}): the model {reason}, so gravity has no direction")
        compute = functools.partial(_projected_gravity, body=body)
        return self._resolved(
            (3,), ("xmat",), compute, _axes(self.body, ("gx", "gy", "gz")), model_fields=("opt.gravity",)
        )


@dataclass(frozen=True)
class SubtreeCom(_BodyReading):
    """The centre of mass of a body and its descendants, in the world frame (``subtree_com`` row): shape ``(3,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import subtree_com
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> subtree_com("torso").resolve(model).fields
        ('subtree_com',)
    """

    kind: ClassVar[str] = "subtree_com"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        compute = functools.partial(_gather_row, name="subtree_com", row=self._body(model), index=_XYZ)
        return self._resolved((3,), ("subtree_com",), compute, _axes(self.body, "xyz"))


@dataclass(frozen=True)
class SubtreeLinVel(_BodyReading):
    """The linear velocity of the centre of mass of a body and its descendants, in the world frame: shape ``(3,)``,
    equal to ``mj_subtreeVel``'s ``subtree_linvel`` (computed here from ``cvel``, ``xipos`` and the per-env masses,
    as the batch fills ``subtree_linvel`` only for a model with a sensor that needs it).

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import subtree_lin_vel
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> subtree_lin_vel("torso").resolve(model).model_fields
        ('body_mass', 'body_subtreemass')
    """

    kind: ClassVar[str] = "subtree_lin_vel"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        body = self._body(model)
        parents = model.body_parentid
        inside = {body}
        for each in range(body + 1, model.nbody):  # a child's id is greater than its parent's
            if int(parents[each]) in inside:
                inside.add(each)
        bodies = sorted(inside)
        position = {each: i for i, each in enumerate(bodies)}
        merges = tuple((position[each], position[int(parents[each])]) for each in reversed(bodies) if each != body)
        compute = functools.partial(
            _subtree_lin_vel,
            body=body,
            bodies=np.array(bodies, dtype=np.int64),
            roots=model.body_rootid[bodies].astype(np.int64),
            merges=merges,
        )
        return self._resolved(
            (3,),
            ("cvel", "xipos", "subtree_com"),
            compute,
            _axes(self.body, ("vx", "vy", "vz")),
            model_fields=("body_mass", "body_subtreemass"),
        )


@dataclass(frozen=True)
class ContactForce(Reading):
    """External forces on bodies (``cfrc_ext`` rows, from ``mj_rnePostConstraint``): shape ``(6 * bodies,)``, for
    each body the torque then the force, in world axes about the centre of mass of the body's tree (MuJoCo's
    com-based frame); every body but the world when none named. The env makes MuJoCo fill ``cfrc_ext``.

    MuJoCo's ``cfrc_ext`` holds the contact forces plus the forces applied through ``xfrc_applied`` (a
    :class:`~torchtasks.transforms.Pushes` force, a user's perturbation), moved to the com-based frame. With
    ``applied=False`` the reading subtracts the latter: the contact forces alone, what a contact termination or a
    contact penalty means (a push then reads as no contact). The default, ``applied=True``, is ``cfrc_ext`` as is
    (Gymnasium's Ant and Humanoid observe it).

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import contact_force
        >>> model = load_model('<mujoco><worldbody><body name="foot"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = contact_force("foot").resolve(model)
        >>> resolved.shape, resolved.contact_forces, resolved.labels[3:]
        ((6,), True, ('foot.fx', 'foot.fy', 'foot.fz'))
    """

    kind: ClassVar[str] = "contact_force"
    bodies: tuple[str, ...] = ()
    #: whether the forces applied through ``xfrc_applied`` count (``cfrc_ext`` as is) or not (contacts alone)
    applied: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "bodies", _check_names(self.bodies, "contact_force bodies", "body"))
        if not isinstance(self.applied, bool):
            raise TypeError(f"contact_force: applied must be a bool, got {self.applied!r}")

    def _arguments(self) -> list[str]:
        return [*self.bodies, *([] if self.applied else ["applied=False"])]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        if self.bodies:
            ids = [object_id(model, "body", name, "contact_force bodies") for name in self.bodies]
        else:
            ids = list(range(1, model.nbody))
        if not ids:
            raise ValueError("contact_force: the model has no body but the world, so no contact force to read")
        names = object_names(model, "body")
        labels = sum((_axes(names[each] or f"body{each}", ("tx", "ty", "tz", "fx", "fy", "fz")) for each in ids), ())
        rows = np.array(ids, dtype=np.int64)
        if self.applied:
            compute = functools.partial(_gather_rows, name="cfrc_ext", rows=rows)
            return self._resolved((6 * len(ids),), ("cfrc_ext",), compute, labels, contact_forces=True)
        compute = functools.partial(_contact_rows, rows=rows, roots=model.body_rootid[rows].astype(np.int64))
        fields = ("cfrc_ext", "xfrc_applied", "xipos", "subtree_com")
        return self._resolved((6 * len(ids),), fields, compute, labels, contact_forces=True)


@dataclass(frozen=True)
class _SiteReading(Reading):
    site: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_name(self.site, f"{self.kind} site", "site")

    def _arguments(self) -> list[str]:
        return [self.site]


@dataclass(frozen=True)
class SitePos(_SiteReading):
    """A site's position in the world frame (``site_xpos`` row): shape ``(3,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import site_pos
        >>> model = load_model('<mujoco><worldbody><body><freejoint/><geom size=".1"/><site name="tip"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> site_pos("tip").resolve(model).fields
        ('site_xpos',)
    """

    kind: ClassVar[str] = "site_pos"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        site = object_id(model, "site", self.site, "site_pos site")
        compute = functools.partial(_gather_row, name="site_xpos", row=site, index=_XYZ)
        return self._resolved((3,), ("site_xpos",), compute, _axes(self.site, "xyz"))


@dataclass(frozen=True)
class SiteQuat(_SiteReading):
    """A site's orientation in the world frame (``site_xquat`` row, w, x, y, z): shape ``(4,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import site_quat
        >>> model = load_model('<mujoco><worldbody><body><freejoint/><geom size=".1"/><site name="tip"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> site_quat("tip").resolve(model).shape
        (4,)
    """

    kind: ClassVar[str] = "site_quat"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        site = object_id(model, "site", self.site, "site_quat site")
        compute = functools.partial(_gather_row, name="site_xquat", row=site, index=_WXYZ)
        return self._resolved((4,), ("site_xquat",), compute, _axes(self.site, ("qw", "qx", "qy", "qz")))


@dataclass(frozen=True)
class GeomPos(Reading):
    """A geom's position in the world frame (``geom_xpos`` row): shape ``(3,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import geom_pos
        >>> model = load_model('<mujoco><worldbody><body><freejoint/><geom name="mouth" size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = geom_pos("mouth").resolve(model)
        >>> resolved.fields, resolved.labels
        (('geom_xpos',), ('mouth.x', 'mouth.y', 'mouth.z'))
    """

    kind: ClassVar[str] = "geom_pos"
    geom: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_name(self.geom, "geom_pos geom", "geom")

    def _arguments(self) -> list[str]:
        return [self.geom]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        geom = object_id(model, "geom", self.geom, "geom_pos geom")
        compute = functools.partial(_gather_row, name="geom_xpos", row=geom, index=_XYZ)
        return self._resolved((3,), ("geom_xpos",), compute, _axes(self.geom, "xyz"))


@dataclass(frozen=True)
class LastAction(Reading):
    """The action of the last step (zeros after a reset), one entry per actuator: shape ``(nu,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import last_action
        >>> model = load_model('<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody>'
        ...                    '<actuator><motor name="m" joint="j"/></actuator></mujoco>')
        >>> resolved = last_action().resolve(model)
        >>> resolved.action, resolved.shape, resolved.fields
        (True, (1,), ())
    """

    kind: ClassVar[str] = "last_action"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        if model.nu == 0:
            raise ValueError("last_action: the model has no actuator, so its actions are empty")
        ids, labels = _actuators(model, (), "last_action")
        compute = functools.partial(_gather, name="action", index=ids)
        return self._resolved((model.nu,), (), compute, labels, action=True)


@dataclass(frozen=True)
class Time(Reading):
    """The simulation time (``time``): shape ``(1,)``.

    Example:
        >>> import numpy as np
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import time
        >>> model = load_model('<mujoco><worldbody><body><joint/><geom size=".1"/></body></worldbody></mujoco>')
        >>> time().resolve(model).compute({"time": np.array([0.0, 0.5])})
        array([[0. ],
               [0.5]])
    """

    kind: ClassVar[str] = "time"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        return self._resolved((1,), ("time",), _time, ("time",))


@dataclass(frozen=True)
class FiniteDifference(Reading):
    """The change of a reading over a step divided by ``dt``, per env (0 after a reset): the inner reading's shape.

    ``dt=None`` divides by the env's control timestep (as Gymnasium's ``x_velocity`` from the body position before
    and after the step). The env keeps the inner reading's value from before the step: the resolved reading names it
    (``difference_of``) and has no ``compute`` of its own. A finite difference of a finite difference is refused,
    and so are ``index`` and ``clip`` (give them to the inner reading).

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_pos, finite_difference
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = finite_difference(body_pos("torso")).resolve(model)
        >>> resolved.label, resolved.difference_of.label, resolved.dt
        ('finite_difference(body_pos(torso))', 'body_pos(torso)', None)
    """

    kind: ClassVar[str] = "finite_difference"
    reading: Reading | None = None
    dt: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.reading, Reading):
            raise TypeError(
                f"finite_difference reading must be a reading (e.g. body_pos('torso')), got {self.reading!r}"
            )
        if isinstance(self.reading, FiniteDifference):
            raise ValueError(f"finite_difference reading must not be a finite difference itself, got {self.reading}")
        if self.clip is not None or self.index is not None:
            raise ValueError(
                f"finite_difference takes no index or clip (give them to its reading), "
                f"got index={self.index}, clip={self.clip}"
            )
        if self.dt is not None:
            if isinstance(self.dt, bool) or not isinstance(self.dt, (int, float, np.integer, np.floating)):
                raise TypeError(f"finite_difference dt must be None or a number of seconds, got {self.dt!r}")
            if not (math.isfinite(self.dt) and self.dt > 0):
                raise ValueError(f"finite_difference dt must be a finite number of seconds > 0, got {self.dt!r}")
            object.__setattr__(self, "dt", float(self.dt))

    def _arguments(self) -> list[str]:
        inner = self.reading._label() if self.reading is not None else "None"
        return [inner, *([] if self.dt is None else [f"dt={self.dt:g}"])]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        inner = self.reading.resolve(model)  # type: ignore[union-attr]
        label = self._label()
        return dataclasses.replace(
            inner,
            label=label,
            difference_of=inner,
            compute=functools.partial(_differenced_by_the_engine, label=label),
            labels=tuple(f"d({each})" for each in inner.labels),
            dt=self.dt,
        )


@dataclass(frozen=True)
class DataField(Reading):
    """Rows ``[start:stop]`` of an ``MjData`` field, flattened: shape ``((stop - start) * row size,)``, e.g. Gymnasium's
    ``cinert[1:]``, ``cvel[1:]`` and ``qfrc_actuator[6:]`` observations. ``name`` is a ``mujoco.batch.Batch.bind``
    field of floating-point values; frames and units are MuJoCo's for that field.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import data_field
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = data_field("cinert", start=1).resolve(model)
        >>> resolved.shape, resolved.fields, resolved.labels[0]
        ((10,), ('cinert',), 'cinert[1, 0]')
    """

    kind: ClassVar[str] = "data_field"
    name: str = ""
    start: int = 0
    stop: int | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_name(self.name, "data_field name", "MjData field")
        if self.name not in mujoco.batch.DATA_FIELDS:
            fields = sorted(mujoco.batch.DATA_FIELDS)
            raise ValueError(
                f"data_field name must be an MjData field the batch binds{did_you_mean(self.name, fields, n=3)}, "
                f"got {self.name!r}"
            )
        if isinstance(self.start, bool) or not isinstance(self.start, (int, np.integer)):
            raise TypeError(f"data_field start must be an int (the first row), got {self.start!r}")
        if self.start < 0:
            raise ValueError(f"data_field start must be >= 0 (the first row), got {self.start}")
        object.__setattr__(self, "start", int(self.start))
        if self.stop is not None:
            if isinstance(self.stop, bool) or not isinstance(self.stop, (int, np.integer)):
                raise TypeError(f"data_field stop must be None or an int (the row after the last), got {self.stop!r}")
            if self.stop <= self.start:
                raise ValueError(f"data_field stop must be above start {self.start}, got {self.stop}")
            object.__setattr__(self, "stop", int(self.stop))

    def _arguments(self) -> list[str]:
        rows = [] if self.start == 0 else [f"start={self.start}"]
        return [self.name, *rows, *([] if self.stop is None else [f"stop={self.stop}"])]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        example = np.asarray(getattr(mujoco.MjData(model), self.name))
        if example.ndim == 0 or not np.issubdtype(example.dtype, np.floating):
            raise ValueError(
                f"data_field({self.name}): the field holds {example.dtype} of shape {example.shape} per env; "
                f"data_field reads rows of floating-point values (time() reads the time)"
            )
        rows = example.shape[0]
        if self.start >= rows:
            raise ValueError(f"data_field({self.name}) start must be below its {rows} rows, got {self.start}")
        if self.stop is not None and self.stop > rows:
            raise ValueError(f"data_field({self.name}) stop must be at most its {rows} rows, got {self.stop}")
        stop = rows if self.stop is None else self.stop
        row_size = int(np.prod(example.shape[1:], dtype=np.int64))
        labels = tuple(
            f"{self.name}[{row}]" if example.ndim == 1 else f"{self.name}[{row}, {i}]"
            for row in range(self.start, stop)
            for i in range(row_size)
        )
        compute = functools.partial(_gather_rows, name=self.name, rows=np.arange(self.start, stop))
        return self._resolved(((stop - self.start) * row_size,), (self.name,), compute, labels)


@dataclass(frozen=True)
class MassCentre(Reading):
    """The centre of mass of the whole model in the world frame, Gymnasium's ``sum(body_mass * xipos) /
    sum(body_mass)`` over all bodies with the per-env masses: shape ``(3,)``.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import mass_centre
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = mass_centre().resolve(model)
        >>> resolved.fields, resolved.model_fields
        (('xipos',), ('body_mass',))
    """

    kind: ClassVar[str] = "mass_centre"

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        return self._resolved((3,), ("xipos",), _mass_centre, ("x", "y", "z"), model_fields=("body_mass",))


def _union(*groups: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(name for group in groups for name in group))


@dataclass(frozen=True)
class _Composite(Reading):
    """A reading computed from other readings, each resolved once: it reads what they read."""

    def _combined(
        self,
        inputs: tuple[Resolved, ...],
        shape: tuple[int, ...],
        compute: Callable[[Mapping[str, Array]], Array],
        labels: tuple[str, ...],
        *,
        fields: tuple[str, ...] = (),
    ) -> Resolved:
        return self._resolved(
            shape,
            _union(*(each.fields for each in inputs), fields),
            compute,
            labels,
            model_fields=_union(*(each.model_fields for each in inputs)),
            contact_forces=any(each.contact_forces for each in inputs),
            action=any(each.action for each in inputs),
        )

    def _call(self) -> str:
        """The reading as written, without its index and clip."""
        return f"{self.kind}({', '.join(self._arguments())})"


@dataclass(frozen=True)
class Difference(_Composite):
    """The difference ``a - b`` of two readings of the same shape: their shape. With ``frame`` (``"body:<name>"``,
    ``"geom:<name>"`` or ``"site:<name>"``) two 3-vectors' difference in that object's frame, ``R^T (a - b)`` with
    ``R`` its rotation in the world (``xmat``, ``geom_xmat`` or ``site_xmat``; dm_control's ``(a - b) @ R``):
    shape ``(3,)``.

    ``index`` and ``clip`` apply to the difference; give ``a`` and ``b`` their own to select or clip before
    subtracting (dm_control's finger: ``difference(sensor("tip"), sensor("spinner"), index=(0, 2))``, the tip's x
    and z relative to the spinner; humanoid: ``difference(body_pos("left_hand"), body_pos("torso"),
    frame="body:torso")``).

    Example:
        >>> import mujoco
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_pos, difference
        >>> model = load_model('<mujoco><worldbody><body name="torso" euler="0 0 90"><geom size=".1"/>'
        ...                    '<body name="hand" pos="1 0 0"><geom size=".1"/></body></body></worldbody></mujoco>')
        >>> data = mujoco.MjData(model)
        >>> mujoco.mj_forward(model, data)
        >>> resolved = difference(body_pos("hand"), body_pos("torso"), frame="body:torso").resolve(model)
        >>> resolved.fields, resolved.labels[0]
        (('xpos', 'xmat'), 'difference(body_pos(hand), body_pos(torso), frame=body:torso).x')
        >>> resolved.compute({"xpos": data.xpos[None], "xmat": data.xmat[None]}).round(12) + 0.0
        array([[1., 0., 0.]])
    """

    kind: ClassVar[str] = "difference"
    a: Reading | None = None
    b: Reading | None = None
    frame: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_reading(self.a, "difference a")
        _check_reading(self.b, "difference b")
        _check_frame(self.frame, "difference frame")

    def _arguments(self) -> list[str]:
        frame = [] if self.frame is None else [f"frame={self.frame}"]
        return [self.a._label(), self.b._label(), *frame]  # type: ignore[union-attr]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        first, second = self.a.resolve(model), self.b.resolve(model)  # type: ignore[union-attr]
        if first.shape != second.shape:
            raise ValueError(
                f"{self._label()}: a and b must have the same shape, got {first.shape} ({first.label}) and "
                f"{second.shape} ({second.label})"
            )
        if self.frame is None:
            rotation, row = None, 0
            labels = tuple(f"{x} - {y}" for x, y in zip(first.labels, second.labels, strict=True))
        else:
            if first.shape != (3,):
                raise ValueError(
                    f"{self._label()}: frame={self.frame} expresses 3-vectors in its axes, so a and b must have "
                    f"shape (3,), got {first.shape} ({first.label}, {second.label})"
                )
            kind, _, name = self.frame.partition(":")
            rotation = _FRAME_ROTATIONS[kind]
            row = object_id(model, kind, name, "difference frame")  # type: ignore[arg-type]
            labels = _axes(self._call(), "xyz")
        compute = functools.partial(_difference, first=first.compute, second=second.compute, rotation=rotation, row=row)
        extra = () if rotation is None else (rotation,)
        return self._combined((first, second), first.shape, compute, labels, fields=extra)


@dataclass(frozen=True)
class Elementwise(_Composite):
    """A function of each element of a reading: ``"log1p"`` (``log(1 + x)``, dm_control's touch sensors) and
    ``"arcsinh"`` (its force and torque sensors) keep the reading's shape; ``"sin_cos"`` gives each element's sine
    and cosine, interleaved (``sin x0, cos x0, sin x1, ...``, dm_control's manipulator ``arm_pos``): shape twice the
    reading's.

    ``index`` and ``clip`` apply to the result. On numpy arrays the values are numpy's functions'; on torch tensors
    torch's, which may differ from numpy's in the last bit.

    Example:
        >>> import numpy as np
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import elementwise, joint_pos
        >>> model = load_model('<mujoco><worldbody><body><joint name="elbow"/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = elementwise(joint_pos("elbow"), "sin_cos").resolve(model)
        >>> resolved.shape, resolved.labels
        ((2,), ('sin(elbow)', 'cos(elbow)'))
        >>> resolved.compute({"qpos": np.array([[0.0], [np.pi / 2]])}).round(12) + 0.0
        array([[0., 1.],
               [1., 0.]])
    """

    kind: ClassVar[str] = "elementwise"
    reading: Reading | None = None
    function: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_reading(self.reading, "elementwise reading")
        if not isinstance(self.function, str):
            raise TypeError(f"elementwise function must be the name of a function (a string), got {self.function!r}")
        if self.function not in _FUNCTIONS:
            raise ValueError(
                f"elementwise function must be one of {list(_FUNCTIONS)}, got {self.function!r}"
                f"{did_you_mean(self.function, list(_FUNCTIONS))}"
            )

    def _arguments(self) -> list[str]:
        return [self.reading._label(), self.function]  # type: ignore[union-attr]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        inner = self.reading.resolve(model)  # type: ignore[union-attr]
        function = _FUNCTIONS[self.function]
        labels = tuple(form.format(label) for label in inner.labels for form in function.labels)
        compute = functools.partial(_elementwise, inner=inner.compute, function=function.compute)
        return self._combined((inner,), (len(labels),), compute, labels)


@dataclass(frozen=True)
class Norm(_Composite):
    """The Euclidean norm of a reading's elements plus ``offset`` (a finite number, 0 by default): shape ``(1,)``.

    dm_control's finger ``dist_to_target``, the target's distance from the tip less the target's radius, is
    ``norm(difference(sensor("target"), sensor("tip"), index=(0, 2)), offset=-0.07)``. ``index`` and ``clip`` apply
    to the norm. A 3-vector's norm is ``mju_norm3``'s on numpy arrays; torch's square root may differ in the last bit.

    Example:
        >>> import numpy as np
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> from torchtasks.envs.readings import body_pos, norm
        >>> model = load_model('<mujoco><worldbody><body name="torso"><freejoint/><geom size=".1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> resolved = norm(body_pos("torso"), offset=-1).resolve(model)
        >>> resolved.label, resolved.shape
        ('norm(body_pos(torso), offset=-1)', (1,))
        >>> resolved.compute({"xpos": np.array([[[0.0, 0.0, 0.0], [3.0, 0.0, 4.0]]])})
        array([[4.]])
    """

    kind: ClassVar[str] = "norm"
    reading: Reading | None = None
    offset: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_reading(self.reading, "norm reading")
        object.__setattr__(self, "offset", _check_number(self.offset, "norm offset"))

    def _arguments(self) -> list[str]:
        offset = [] if self.offset == 0 else [f"offset={self.offset:g}"]
        return [self.reading._label(), *offset]  # type: ignore[union-attr]

    def _resolve(self, model: mujoco.MjModel) -> Resolved:
        inner = self.reading.resolve(model)  # type: ignore[union-attr]
        compute = functools.partial(_norm, inner=inner.compute, offset=self.offset)
        return self._combined((inner,), (1,), compute, (self._call(),))


#: every reading kind: its name (the constructor function's) -> its class
READING_KINDS: dict[str, type[Reading]] = {
    kind.kind: kind
    for kind in (
        JointPos,
        JointVel,
        ActuatorCtrl,
        ActuatorForce,
        Sensor,
        BodyPos,
        BodyQuat,
        BodyLinVel,
        BodyAngVel,
        ProjectedGravity,
        SubtreeCom,
        SubtreeLinVel,
        ContactForce,
        SitePos,
        SiteQuat,
        GeomPos,
        LastAction,
        Time,
        FiniteDifference,
        DataField,
        MassCentre,
        Difference,
        Elementwise,
        Norm,
    )
}


# ---------------------------------------------------------------------------------------------------- constructors
Clip = tuple[float, float] | None
Index = Sequence[int] | None


def joint_pos(*joints: str, relative_to: str | None = None, index: Index = None, clip: Clip = None) -> JointPos:
    """Positions of ``joints`` (all when none), optionally relative to ``"qpos0"`` or a keyframe: see :class:`JointPos`.

    Example:
        >>> joint_pos("knee", "hip", relative_to="home")
        JointPos(index=None, clip=None, joints=('knee', 'hip'), relative_to='home')
    """
    return JointPos(joints=joints, relative_to=relative_to, index=index, clip=clip)


def joint_vel(*joints: str, index: Index = None, clip: Clip = None) -> JointVel:
    """Velocities of ``joints`` (all when none): see :class:`JointVel`.

    Example:
        >>> joint_vel("knee").joints
        ('knee',)
    """
    return JointVel(joints=joints, index=index, clip=clip)


def actuator_ctrl(*actuators: str, index: Index = None, clip: Clip = None) -> ActuatorCtrl:
    """Controls of ``actuators`` (all when none): see :class:`ActuatorCtrl`.

    Example:
        >>> actuator_ctrl("hip_motor").kind
        'actuator_ctrl'
    """
    return ActuatorCtrl(actuators=actuators, index=index, clip=clip)


def actuator_force(*actuators: str, index: Index = None, clip: Clip = None) -> ActuatorForce:
    """Forces of ``actuators`` (all when none): see :class:`ActuatorForce`.

    Example:
        >>> actuator_force().actuators
        ()
    """
    return ActuatorForce(actuators=actuators, index=index, clip=clip)


def sensor(name: str, *, index: Index = None, clip: Clip = None) -> Sensor:
    """The data of the sensor ``name``: see :class:`Sensor`.

    Example:
        >>> sensor("imu_gyro", clip=(-20, 20)).clip
        (-20.0, 20.0)
    """
    return Sensor(name=name, index=index, clip=clip)


def body_pos(body: str, *, point: str = "origin", index: Index = None, clip: Clip = None) -> BodyPos:
    """The world position of ``body``'s frame origin or (``point="com"``) centre of mass (``index=(2,)``: its
    height): see :class:`BodyPos`.

    Example:
        >>> body_pos("torso", index=(2,)).index
        (2,)
        >>> body_pos("torso", point="com").point
        'com'
    """
    return BodyPos(body=body, point=point, index=index, clip=clip)


def body_quat(body: str, *, index: Index = None, clip: Clip = None) -> BodyQuat:
    """The world orientation of ``body``'s frame: see :class:`BodyQuat`.

    Example:
        >>> body_quat("torso").kind
        'body_quat'
    """
    return BodyQuat(body=body, index=index, clip=clip)


def body_lin_vel(
    body: str, *, frame: str = "world", point: str = "origin", index: Index = None, clip: Clip = None
) -> BodyLinVel:
    """The linear velocity of ``body``'s origin or centre of mass, in world or local axes: see :class:`BodyLinVel`.

    Example:
        >>> body_lin_vel("torso", frame="local", point="com").point
        'com'
    """
    return BodyLinVel(body=body, frame=frame, point=point, index=index, clip=clip)


def body_ang_vel(
    body: str, *, frame: str = "world", point: str = "origin", index: Index = None, clip: Clip = None
) -> BodyAngVel:
    """The angular velocity of ``body``, in world or local axes: see :class:`BodyAngVel`.

    Example:
        >>> body_ang_vel("torso", frame="local").frame
        'local'
    """
    return BodyAngVel(body=body, frame=frame, point=point, index=index, clip=clip)


def projected_gravity(body: str, *, index: Index = None, clip: Clip = None) -> ProjectedGravity:
    """The unit gravity direction in ``body``'s frame: see :class:`ProjectedGravity`.

    Example:
        >>> projected_gravity("torso").kind
        'projected_gravity'
    """
    return ProjectedGravity(body=body, index=index, clip=clip)


def subtree_com(body: str, *, index: Index = None, clip: Clip = None) -> SubtreeCom:
    """The centre of mass of ``body``'s subtree: see :class:`SubtreeCom`.

    Example:
        >>> subtree_com("torso").body
        'torso'
    """
    return SubtreeCom(body=body, index=index, clip=clip)


def subtree_lin_vel(body: str, *, index: Index = None, clip: Clip = None) -> SubtreeLinVel:
    """The velocity of the centre of mass of ``body``'s subtree: see :class:`SubtreeLinVel`.

    Example:
        >>> subtree_lin_vel("torso").kind
        'subtree_lin_vel'
    """
    return SubtreeLinVel(body=body, index=index, clip=clip)


def contact_force(*bodies: str, index: Index = None, clip: Clip = None, applied: bool = True) -> ContactForce:
    """The external forces on ``bodies`` (every body but the world when none), with the forces applied through
    ``xfrc_applied`` or (``applied=False``) the contacts alone: see :class:`ContactForce`.

    Example:
        >>> contact_force("left_foot", "right_foot", clip=(-1, 1)).bodies
        ('left_foot', 'right_foot')
        >>> contact_force("torso", applied=False).applied  # a push of the torso is no contact
        False
    """
    return ContactForce(bodies=bodies, index=index, clip=clip, applied=applied)


def site_pos(site: str, *, index: Index = None, clip: Clip = None) -> SitePos:
    """The world position of ``site``: see :class:`SitePos`.

    Example:
        >>> site_pos("fingertip").site
        'fingertip'
    """
    return SitePos(site=site, index=index, clip=clip)


def site_quat(site: str, *, index: Index = None, clip: Clip = None) -> SiteQuat:
    """The world orientation of ``site``: see :class:`SiteQuat`.

    Example:
        >>> site_quat("fingertip").kind
        'site_quat'
    """
    return SiteQuat(site=site, index=index, clip=clip)


def geom_pos(geom: str, *, index: Index = None, clip: Clip = None) -> GeomPos:
    """The world position of ``geom``: see :class:`GeomPos`.

    Example:
        >>> geom_pos("target", index=(0, 1)).geom
        'target'
    """
    return GeomPos(geom=geom, index=index, clip=clip)


def last_action(*, index: Index = None, clip: Clip = None) -> LastAction:
    """The last action: see :class:`LastAction`.

    Example:
        >>> last_action() == last_action()
        True
    """
    return LastAction(index=index, clip=clip)


def time(*, index: Index = None, clip: Clip = None) -> Time:
    """The simulation time: see :class:`Time`.

    Example:
        >>> time().kind
        'time'
    """
    return Time(index=index, clip=clip)


def finite_difference(reading: Reading, dt: float | None = None) -> FiniteDifference:
    """The change of ``reading`` over a step divided by ``dt`` (the control timestep when None): see
    :class:`FiniteDifference`.

    Example:
        >>> finite_difference(body_pos("torso"), dt=0.05).dt
        0.05
    """
    return FiniteDifference(reading=reading, dt=dt)


def data_field(
    name: str, start: int = 0, stop: int | None = None, *, index: Index = None, clip: Clip = None
) -> DataField:
    """Rows ``[start:stop]`` of the ``MjData`` field ``name``, flattened: see :class:`DataField`.

    Example:
        >>> data_field("qpos", 0, 1).stop
        1
    """
    return DataField(name=name, start=start, stop=stop, index=index, clip=clip)


def mass_centre(*, index: Index = None, clip: Clip = None) -> MassCentre:
    """The model's centre of mass: see :class:`MassCentre`.

    Example:
        >>> mass_centre().kind
        'mass_centre'
    """
    return MassCentre(index=index, clip=clip)


def difference(
    a: Reading, b: Reading, *, frame: str | None = None, index: Index = None, clip: Clip = None
) -> Difference:
    """``a - b``, two readings of the same shape; with ``frame`` (``"body:<name>"``, ``"geom:<name>"`` or
    ``"site:<name>"``) two 3-vectors' difference in that object's frame: see :class:`Difference`.

    Example:
        >>> difference(geom_pos("target"), geom_pos("mouth"), frame="geom:mouth").frame
        'geom:mouth'
    """
    return Difference(a=a, b=b, frame=frame, index=index, clip=clip)


def elementwise(reading: Reading, function: str, *, index: Index = None, clip: Clip = None) -> Elementwise:
    """``function`` (``"log1p"``, ``"arcsinh"`` or ``"sin_cos"``) of each element of ``reading``: see
    :class:`Elementwise`.

    Example:
        >>> elementwise(sensor("touch"), "log1p").function
        'log1p'
    """
    return Elementwise(reading=reading, function=function, index=index, clip=clip)


def norm(reading: Reading, *, offset: float = 0.0, index: Index = None, clip: Clip = None) -> Norm:
    """The Euclidean norm of ``reading``'s elements plus ``offset``: see :class:`Norm`.

    Example:
        >>> norm(site_pos("tip"), offset=-0.05).offset
        -0.05
    """
    return Norm(reading=reading, offset=offset, index=index, clip=clip)
