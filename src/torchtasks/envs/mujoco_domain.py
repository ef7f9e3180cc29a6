"""The domain fields of a MuJoCo model in a ``mujoco.batch.Batch``: one table of field kinds, checks and writes.

:data:`FIELD_KINDS` is the one table (one row per kind of field: its model field, the objects it is offered for,
its allowed range, the fields that follow it, whether ``mj_setConst`` must run after it).
:class:`BatchDomain` reads it for one batch: the :class:`~torchtasks.domain.DomainField` of each named object,
the checks of the values users write, and the writes into the batch's per-simulation model fields
(``Batch.expand``; a field never written stays shared, so an env never randomized does no extra work).
:class:`~torchtasks.envs.BatchedMujocoEnv` offers it through the :class:`~torchtasks.domain.DomainEnv` methods.

Names (:mod:`torchtasks.domain.fields`): ``"<kind>:<object>"`` for one named object's value, ``"<kind>_scale"`` for a
factor on every object's value, ``"gravity"`` for the global one. Objects are the model's named bodies (not the
world body; for masses not a body of mass 0, whose inertia could not follow), geoms, sites, joints and actuators (an
unnamed actuator of a joint by its joint's name: Hopper's ``actuator_gear:thigh_joint``); an unnamed object or a name
holding ``"."`` or ``"/"`` is not offered. Positions and orientations (``body_pos``, ``body_quat``, ``geom_pos``,
``site_pos``: a target placed per episode, an object moved) are an object's row (3 or 4 values) and have no scale.
The model's value of an object is its own value (nominal until set) times the kind's scale (1.0 until set): a scale
and one object's value set by two ``set_domain`` calls compose.

Actuator gains are offered only for the actuators whose compiled parameters have that meaning (MuJoCo's force is
``gain * ctrl + bias``, here with a fixed gain ``gainprm[0]`` and an affine bias
``biasprm[0] + biasprm[1] * length + biasprm[2] * velocity``), and a value writes every parameter that holds it:

- ``actuator_kp:<actuator>``: a position servo's stiffness (``<position>``, ``<intvelocity>``, a ``<general>`` with
  ``biasprm[1] == -gainprm[0] > 0``): ``gainprm[0] = kp`` and ``biasprm[1] = -kp``, never one without the other;
- ``actuator_kv:<actuator>``: a servo's damping, ``biasprm[2] = -kv``: a position servo's (0 when it has none, as the
  shipped quadruped's) and a velocity servo's (``<velocity>``: ``biasprm[1] == 0``, ``biasprm[2] == -gainprm[0] > 0``),
  whose ``gainprm[0] = kv`` is written too;
- ``actuator_gain:<actuator>``: a motor's strength (``<motor>``, a fixed gain ``> 0`` and no bias): ``gainprm[0]``.
  It scales the control into the actuator's force only; ``actuator_gear`` also scales the moment arm (the force's
  transmission to the joint, tendon or site, and the actuator length and velocity a servo's bias reads), and
  ``mj_setConst`` recomputes what derives from it.

``mj_setConst`` reads neither ``gainprm`` nor ``biasprm``: gains are written without it.

The env may own fields beside the model's (:class:`~torchtasks.envs.BatchedMujocoEnv`'s ``"action_delay"``): given to
:class:`BatchDomain` as ``env_fields``, they are named, checked, kept and saved with the model's, in the same table;
their values write no model field (the env reads them where its own semantics say).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import numpy as np
import torch

from torchtasks._did_you_mean import did_you_mean
from torchtasks._optional import missing_extra
from torchtasks.domain.fields import DomainField, check_domain_values, select_fields

try:
    import mujoco
    from mujoco.batch import Batch
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.mujoco_domain", _error) from _error

__all__ = ["FIELD_KINDS", "BatchDomain", "Coupled", "FieldKind", "domain_field"]

#: the suffix of a kind's scale field
SCALE = "_scale"


#: which objects of a kind are meant: ``model -> bool [number of objects]``
Objects = Callable[[mujoco.MjModel], np.ndarray]


class Coupled(NamedTuple):
    """A model value written together with a kind's own: ``factor`` times the field's value, in one column.

    Example:
        >>> kp = next(kind for kind in FIELD_KINDS if kind.stem == "actuator_kp")
        >>> kp.coupled  # a position servo's kp is gainprm[0] (the kind's own column) and -biasprm[1]
        (Coupled(model_field='actuator_biasprm', column=1, factor=-1.0, where=None),)
        >>> kp.model_fields
        ('actuator_gainprm', 'actuator_biasprm')
    """

    #: the model field (``Batch.expand``'s name)
    model_field: str
    #: the column of the field's row written
    column: int
    #: the model value is ``factor`` times the field's value (``-1.0``: a servo's ``biasprm[1] = -kp``)
    factor: float
    #: the objects it is written for, among those the kind offers; ``None``: all of them
    where: Objects | None = None


class FieldKind(NamedTuple):
    """One kind of domain field: a model field, the objects it has one value for, its range and its follow-ups."""

    #: the names' stem (``"body_mass"`` gives ``"body_mass:<body>"`` and ``"body_mass_scale"``)
    stem: str
    #: the model field the values are written into (``Batch.expand``'s name)
    model_field: str
    #: the kind of named object with one value each (``"body"``, ``"geom"``, ``"site"``, ``"joint"``, ``"actuator"``);
    #: ``None``: one global value, the whole field
    objects: str | None
    #: the column of the model field's row that is the value (``geom_friction[:, 0]``, the sliding friction); ``None``:
    #: the whole row
    column: int | None
    #: the smallest allowed value of one object (excluded when ``low_open``); the largest is always ``inf``
    low: float
    low_open: bool
    #: ``None``: no scale field; else whether a scale of 0 is refused (a scale's range is ``(0, inf)`` or ``[0, inf)``)
    scale_low_open: bool | None
    #: model fields multiplied per object by the object's value over its nominal one (a body's inertia follows its
    #: mass: the same shape of uniform density, as IsaacLab's ``recompute_inertia``)
    scaled_with: tuple[str, ...]
    #: whether ``mj_setConst`` reads the model field (``mujoco.MjModel._setconst_inputs``): the batch's ``set_const``
    #: must then recompute the derived constants of the simulations written
    set_const: bool
    #: what one object's value is (``{}``: the object's name)
    what: str
    #: what the scale does
    scale_what: str
    #: ``model_field``'s value is ``factor`` times the field's (``-1.0``: a damping stored as ``biasprm[2] = -kv``);
    #: 1.0 or -1.0, so that reading the nominal value and writing it back are exact
    factor: float = 1.0
    #: other model values written with each value, never one without the other (a servo's ``kp`` is ``gainprm[0]`` and
    #: ``-biasprm[1]``)
    coupled: tuple[Coupled, ...] = ()
    #: which objects the kind is meant for (one-object fields and what the scale multiplies; a motor has no ``kp``);
    #: ``None``: every object
    offered: Objects | None = None

    @property
    def model_fields(self) -> tuple[str, ...]:
        """Every model field a value of the kind writes, each once."""
        return tuple(dict.fromkeys((self.model_field, *(c.model_field for c in self.coupled), *self.scaled_with)))


def _fixed_gain(model: mujoco.MjModel, bias: mujoco.mjtBias) -> np.ndarray:
    """Per actuator: a fixed gain (``force = gainprm[0] * ctrl + bias``) and bias type ``bias``."""
    return (model.actuator_gaintype == int(mujoco.mjtGain.mjGAIN_FIXED)) & (model.actuator_biastype == int(bias))


def _position_servo(model: mujoco.MjModel) -> np.ndarray:
    """Per actuator: a position servo, a fixed gain ``kp > 0`` and an affine bias with ``biasprm[1] == -kp``
    (``force = kp * (ctrl - length) - kv * velocity + biasprm[0]``): MuJoCo's ``<position>``, ``<intvelocity>`` (on
    its activation), a ``<general>`` written so."""
    gain, bias = model.actuator_gainprm, model.actuator_biasprm
    return _fixed_gain(model, mujoco.mjtBias.mjBIAS_AFFINE) & (gain[:, 0] > 0) & (bias[:, 1] == -gain[:, 0])


def _velocity_servo(model: mujoco.MjModel) -> np.ndarray:
    """Per actuator: a velocity servo, a fixed gain ``kv > 0`` and an affine bias with ``biasprm[1] == 0`` and
    ``biasprm[2] == -kv`` (``force = kv * (ctrl - velocity) + biasprm[0]``): MuJoCo's ``<velocity>``."""
    gain, bias = model.actuator_gainprm, model.actuator_biasprm
    affine = _fixed_gain(model, mujoco.mjtBias.mjBIAS_AFFINE)
    return affine & (gain[:, 0] > 0) & (bias[:, 1] == 0) & (bias[:, 2] == -gain[:, 0])


def _damped_servo(model: mujoco.MjModel) -> np.ndarray:
    """Per actuator: a servo with a damping ``kv = -biasprm[2] >= 0``, a position servo (``kv`` 0 when none was
    given) or a velocity servo."""
    return _velocity_servo(model) | (_position_servo(model) & (model.actuator_biasprm[:, 2] <= 0))


def _motor(model: mujoco.MjModel) -> np.ndarray:
    """Per actuator: a motor, a fixed gain ``> 0`` and no bias (``force = gainprm[0] * ctrl``): MuJoCo's ``<motor>``
    (gain 1), a ``<general>`` with a gain."""
    return _fixed_gain(model, mujoco.mjtBias.mjBIAS_NONE) & (model.actuator_gainprm[:, 0] > 0)


#: The field kinds, in the order :meth:`BatchDomain.fields` lists them. ``set_const`` follows
#: ``MjModel._setconst_inputs`` (``body_mass``, ``body_inertia``, ``dof_armature``, ``actuator_gear``; not
#: ``geom_friction``, ``dof_damping``, ``actuator_gainprm``, ``actuator_biasprm``: the quadruped and an arm of each
#: kind of servo with other gains are bit-identical, all 487 arrays, before and after ``mj_setConst`` on MuJoCo 4.0.0;
#: a ``<position dampratio=...>``'s kv is resolved by the compiler, so a kp written later keeps the compiled kv).
#: Gravity needs none: ``mj_setConst`` reads no ``opt`` field (``mjxmacro.h``'s
#: ``MJSETCONST_ARRAYS`` lists arrays only, and a model with another gravity is bit-identical before and after
#: ``mj_setConst`` for every supported env), and ``mujoco.batch``'s own test steps per-simulation gravity without it.
FIELD_KINDS: tuple[FieldKind, ...] = (
    FieldKind(
        stem="body_mass", model_field="body_mass", objects="body", column=None, low=0.0, low_open=True,
        scale_low_open=True, scaled_with=("body_inertia",), set_const=True,
        what="mass of body {} (kg; its inertia follows)", scale_what="every body's mass and inertia times this factor",
    ),
    FieldKind(
        stem="geom_friction", model_field="geom_friction", objects="geom", column=0, low=0.0, low_open=False,
        scale_low_open=False, scaled_with=(), set_const=False,
        what="sliding friction of geom {}", scale_what="every geom's sliding friction times this factor",
    ),
    FieldKind(
        stem="dof_damping", model_field="dof_damping", objects="joint", column=None, low=0.0, low_open=False,
        scale_low_open=False, scaled_with=(), set_const=False,
        what="damping of joint {} (per dof)", scale_what="every dof's damping times this factor",
    ),
    FieldKind(
        stem="dof_armature", model_field="dof_armature", objects="joint", column=None, low=0.0, low_open=False,
        scale_low_open=False, scaled_with=(), set_const=True,
        what="armature of joint {} (per dof)", scale_what="every dof's armature times this factor",
    ),
    FieldKind(
        stem="actuator_gear", model_field="actuator_gear", objects="actuator", column=0, low=-math.inf, low_open=False,
        scale_low_open=True, scaled_with=(), set_const=True,
        what="gear of actuator {} (any finite value: a negative gear reverses the actuator)",
        scale_what="every actuator's gear times this factor (> 0: a scale never reverses an actuator)",
    ),
    FieldKind(
        stem="actuator_kp", model_field="actuator_gainprm", objects="actuator", column=0, low=0.0, low_open=True,
        scale_low_open=True, scaled_with=(), set_const=False,
        what="stiffness kp of position servo {} (gainprm[0] = kp and biasprm[1] = -kp, written together; > 0: a kp of "
        "0 ignores the control, a negative one pushes away from the target)",
        scale_what="every position servo's kp times this factor",
        coupled=(Coupled("actuator_biasprm", 1, -1.0),), offered=_position_servo,
    ),
    FieldKind(
        stem="actuator_kv", model_field="actuator_biasprm", objects="actuator", column=2, low=0.0, low_open=False,
        scale_low_open=True, scaled_with=(), set_const=False,
        what="damping kv of servo {} (biasprm[2] = -kv; a velocity servo's gainprm[0] = kv too; >= 0: a negative kv "
        "adds energy; a velocity servo with kv 0 does nothing)",
        scale_what="every servo's kv times this factor (> 0: a scale never stops a velocity servo)",
        factor=-1.0, coupled=(Coupled("actuator_gainprm", 0, 1.0, where=_velocity_servo),), offered=_damped_servo,
    ),
    FieldKind(
        stem="actuator_gain", model_field="actuator_gainprm", objects="actuator", column=0, low=0.0, low_open=True,
        scale_low_open=True, scaled_with=(), set_const=False,
        what="gain of motor {} (gainprm[0]: force = gain * control, before the gear; > 0: actuator_gear reverses)",
        scale_what="every motor's gain times this factor",
        offered=_motor,
    ),
    FieldKind(
        stem="body_pos", model_field="body_pos", objects="body", column=None, low=-math.inf, low_open=False,
        scale_low_open=None, scaled_with=(), set_const=True,
        what="position of body {} in its parent's frame (m; a target or an object placed per episode)",
        scale_what="",
    ),
    FieldKind(
        stem="body_quat", model_field="body_quat", objects="body", column=None, low=-math.inf, low_open=False,
        scale_low_open=None, scaled_with=(), set_const=True,
        what="orientation of body {} in its parent's frame (a unit quaternion w, x, y, z)", scale_what="",
    ),
    FieldKind(
        stem="geom_pos", model_field="geom_pos", objects="geom", column=None, low=-math.inf, low_open=False,
        scale_low_open=None, scaled_with=(), set_const=True,
        what="position of geom {} in its body's frame (m)", scale_what="",
    ),
    FieldKind(
        stem="site_pos", model_field="site_pos", objects="site", column=None, low=-math.inf, low_open=False,
        scale_low_open=None, scaled_with=(), set_const=True,
        what="position of site {} in its body's frame (m)", scale_what="",
    ),
    FieldKind(
        stem="gravity", model_field="opt.gravity", objects=None, column=None, low=-math.inf, low_open=False,
        scale_low_open=None, scaled_with=(), set_const=False,
        what="gravity (m/s^2, world frame)", scale_what="",
    ),
)  # fmt: skip

#: the model's count of each kind of object
_COUNTS = {"body": "nbody", "geom": "ngeom", "site": "nsite", "joint": "njnt", "actuator": "nu"}
#: the dofs of a joint, by type
_JOINT_DOFS = {
    int(mujoco.mjtJoint.mjJNT_FREE): 6,
    int(mujoco.mjtJoint.mjJNT_BALL): 3,
    int(mujoco.mjtJoint.mjJNT_SLIDE): 1,
    int(mujoco.mjtJoint.mjJNT_HINGE): 1,
}


def _nominal_rows(field: DomainField, nsim: int) -> np.ndarray:
    """``field``'s nominal value in every row: float64 ``[nsim, *value_shape]`` (a new array)."""
    return np.broadcast_to(field.nominal.numpy(), (nsim, *field.value_shape)).copy()


class _Entry(NamedTuple):
    """A field of the table: what users see, its kind, and the columns of the kind's values it covers."""

    field: DomainField
    kind: FieldKind
    #: the columns of the kind's values (one per body, geom, dof or actuator; gravity's 3) it writes; ``None``: a scale
    slots: np.ndarray | None


def _model_value(model: mujoco.MjModel, name: str) -> np.ndarray:
    """The model's array of field ``name`` (``"opt.<name>"`` for an ``MjOption`` field)."""
    return np.asarray(getattr(model.opt, name[4:]) if name.startswith("opt.") else getattr(model, name))


def _kind_values(array: np.ndarray, kind: FieldKind) -> np.ndarray:
    """The columns of a model field (``[..., rows, columns]``) that are ``kind``'s values: a view."""
    return array if kind.column is None else array[..., kind.column]


def _times(factor: float, values: np.ndarray) -> np.ndarray:
    """``factor * values`` (``values`` itself for 1.0); for -1.0 a zero stays 0.0, so that a model's 0.0 read as a
    value (``kv = -biasprm[2]``) and written back is the same 0.0."""
    return values if factor == 1.0 else factor * values + 0.0


def _object_slots(model: mujoco.MjModel, kind: FieldKind, i: int) -> np.ndarray:
    """The columns of ``kind``'s values that object ``i`` covers: a joint's dofs, else the object's own."""
    if kind.objects == "joint":
        start = int(model.jnt_dofadr[i])
        return np.arange(start, start + _JOINT_DOFS[int(model.jnt_type[i])])
    return np.array([i])


def _covered(model: mujoco.MjModel, kind: FieldKind, where: Objects | None = None) -> np.ndarray | None:
    """The columns of ``kind``'s values of every object (named or not) the kind is offered for and ``where`` selects:
    what a scale multiplies and a coupled value is written for; ``None``: every column (a kind for every object)."""
    if kind.offered is None and where is None:
        return None
    chosen = np.ones(getattr(model, _COUNTS[kind.objects]), dtype=bool)
    for select in (kind.offered, where):
        chosen &= True if select is None else select(model)
    slots = [_object_slots(model, kind, i) for i in np.flatnonzero(chosen).tolist()]
    columns = np.concatenate(slots) if slots else np.zeros(0, dtype=np.int64)
    every = _kind_values(_model_value(model, kind.model_field), kind).shape[0]
    # every column in order: None, the plain write (a fancy index of rows and columns costs ~10 us at each write)
    return None if np.array_equal(columns, np.arange(every)) else columns


def _nominal_values(model: mujoco.MjModel, kind: FieldKind) -> np.ndarray:
    """``kind``'s values in ``model`` (every object's, offered or not): a new array."""
    return _times(kind.factor, _kind_values(_model_value(model, kind.model_field), kind)).copy()


def _objects(model: mujoco.MjModel, kind: FieldKind, nominal: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The objects offered for ``kind``: (name, the columns of the kind's values it covers)."""
    if kind.objects is None:
        return []
    offered = []
    meant = None if kind.offered is None else kind.offered(model)
    for i in range(getattr(model, _COUNTS[kind.objects])):
        name = getattr(model, kind.objects)(i).name
        if not name and kind.objects == "actuator" and model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT:
            name = model.joint(int(model.actuator_trnid[i, 0])).name  # an unnamed actuator: named by its joint
        if not name or "." in name or "/" in name or (kind.objects == "body" and i == 0):
            continue
        if meant is not None and not meant[i]:  # a motor has no kp
            continue
        slots = _object_slots(model, kind, i)
        if kind.scaled_with and not (nominal[slots] > 0).all():  # nothing can follow a value of 0 by its ratio
            continue
        if any(name == other for other, _ in offered):  # a joint's name an actuator already has: not offered twice
            continue
        offered.append((name, slots))
    return offered


def _table(model: mujoco.MjModel) -> dict[str, _Entry]:
    """Every field of ``model``, by name, in :data:`FIELD_KINDS`' order (objects in id order, then the scale)."""
    table: dict[str, _Entry] = {}
    for kind in FIELD_KINDS:
        nominal = _nominal_values(model, kind)
        common = {"high": math.inf, "model_fields": kind.model_fields, "set_const": kind.set_const}
        if kind.objects is None:
            entries = [(kind.stem, np.arange(nominal.size), kind.what)]
        else:
            entries = [
                (f"{kind.stem}:{name}", slots, kind.what.format(repr(name)))
                for name, slots in _objects(model, kind, nominal)
            ]
        for name, slots, what in entries:
            value = torch.tensor(nominal[slots], dtype=torch.float64)
            if kind.objects is not None and slots.size == 1:  # one body, geom, site, dof or actuator: its value
                value = value[0]  # a scalar (a mass), or the object's row (a position, a quaternion)
            field = DomainField(
                name, value.shape, value, low=kind.low, low_open=kind.low_open, description=what, **common
            )
            table[name] = _Entry(field, kind, slots)
        covered = _covered(model, kind)
        if kind.scale_low_open is not None and (covered is None or covered.size):  # a scale of nothing: not offered
            one = torch.tensor(1.0, dtype=torch.float64)
            name = kind.stem + SCALE
            field = DomainField(
                name, one.shape, one, low=0.0, low_open=kind.scale_low_open, description=kind.scale_what, **common
            )
            table[name] = _Entry(field, kind, None)
    return table


def domain_field(model: mujoco.MjModel, name: str, argument: str) -> DomainField:
    """The domain field ``name`` of ``model`` (its nominal value and allowed range); ``ValueError`` naming
    ``argument`` and the closest names for a field the model does not offer.

    Example:
        >>> import mujoco
        >>> model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body name="box"><freejoint/>'
        ...                                        '<geom type="box" size="0.1 0.1 0.1"/></body></worldbody></mujoco>')
        >>> domain_field(model, "body_mass:box", "field").rule
        'in (0.0, inf)'
    """
    table = _table(model)
    if not isinstance(name, str) or name not in table:
        raise ValueError(
            f"{argument}: the model offers no domain field {name!r}{did_you_mean(str(name), list(table))} (kinds: "
            + ", ".join(kind.stem + ("" if kind.objects is None else f":<{kind.objects}>") for kind in FIELD_KINDS)
            + ")"
        )
    return table[name].field


class BatchDomain:
    """The domain fields of a batch's model and the per-simulation values set so far.

    ``values`` holds each field ever set: ``name -> float64 [nsim, *value_shape]`` (nominal in the rows never set).
    The model fields of a kind are written from them (:meth:`write`) for the simulations written only; the kinds never
    written are never expanded.

    Args:
        model: the batch's model (its values are the nominal ones).
        batch: the batch to write into.
        owner: who offers the fields, for messages (``"BatchedMujocoEnv(Hopper-v5)"``).
        env_fields: fields the env owns beside the model's, listed after them: checked, kept in ``values`` and
            saved like the model's, written into no model field (the env reads their values).

    Example:
        >>> import mujoco, numpy as np
        >>> from mujoco.batch import Batch
        >>> model = mujoco.MjModel.from_xml_string(
        ...     '<mujoco><worldbody><body name="box"><freejoint name="free"/><geom name="cube" type="box" '
        ...     'size=".1 .1 .1" mass="2"/></body></worldbody></mujoco>')
        >>> batch = Batch(model, 2)
        >>> domain = BatchDomain(model, batch, "a box")
        >>> [field.name for field in domain.fields()][:4]
        ['body_mass:box', 'body_mass_scale', 'geom_friction:cube', 'geom_friction_scale']
        >>> import torch
        >>> first = torch.tensor([True, False])  # write simulation 0 only
        >>> masses = {"body_mass:box": torch.tensor([3.0, 9.0], dtype=torch.float64)}
        >>> rows, ids = domain.checked(masses, first, "values")
        >>> kinds = domain.write(rows, ids)  # the mass, the inertia that follows, set_const on simulation 0
        >>> batch.expanded("body_mass")[:, 1], batch.expanded("geom_friction") is None
        (array([3., 2.]), True)
    """

    def __init__(self, model: mujoco.MjModel, batch: Batch, owner: str, env_fields: Sequence[DomainField] = ()) -> None:
        self.model, self.batch, self.owner = model, batch, owner
        self.table = _table(model)
        clash = [field.name for field in env_fields if field.name in self.table]
        if clash:
            raise ValueError(f"{owner}: the env's own domain fields {clash} have the names of model fields")
        #: per kind: the columns of its values written (a scale's; ``None``: all), and per coupled value ``k`` of the
        #: kind, under ``(stem, k)``, the columns it is written for
        self._covers: dict[object, np.ndarray | None] = {}
        for kind in FIELD_KINDS:
            self._covers[kind.stem] = _covered(model, kind)
            for k, coupled in enumerate(kind.coupled):
                self._covers[kind.stem, k] = _covered(model, kind, coupled.where)
        #: the model values each field writes: (model field, column of its rows, column of the kind's values); two
        #: fields named together must write none in common
        self.writes = {name: self._written(entry) for name, entry in self.table.items()}
        self.writes.update({field.name: frozenset({(field.name, None, 0)}) for field in env_fields})
        self.values: dict[str, np.ndarray] = {}
        #: every field by name: the model's (``table``), then the env's own
        self._fields = {name: entry.field for name, entry in self.table.items()}
        self._fields.update({field.name: field for field in env_fields})
        #: per kind: the model's (nominal) values, the one-object fields, and the model values that follow the kind
        self._nominals = {kind.stem: _nominal_values(model, kind) for kind in FIELD_KINDS}
        self._kind_fields = {
            kind.stem: [name for name, entry in self.table.items() if entry.kind is kind and entry.slots is not None]
            for kind in FIELD_KINDS
        }
        self._followers = {name: _model_value(model, name).copy() for kind in FIELD_KINDS for name in kind.scaled_with}
        self._kinds = ", ".join(
            kind.stem + ("" if kind.objects is None else f":<{kind.objects}>")
            + ("" if kind.scale_low_open is None else f", {kind.stem}{SCALE}")
            for kind in FIELD_KINDS
        ) + "".join(f", {field.name}" for field in env_fields)  # fmt: skip

    def _written(self, entry: _Entry) -> frozenset[tuple[str, int | None, int]]:
        """The model values a field writes: ``(model field, column, slot)`` of its own and of its coupled values."""
        kind = entry.kind
        slots = entry.slots if entry.slots is not None else self._covers[kind.stem]
        if slots is None:
            slots = np.arange(_kind_values(_model_value(self.model, kind.model_field), kind).shape[0])
        written = {(kind.model_field, kind.column, int(slot)) for slot in slots}
        for k, coupled in enumerate(kind.coupled):
            where = self._covers[kind.stem, k]
            both = slots if where is None else np.intersect1d(slots, where)
            written |= {(coupled.model_field, coupled.column, int(slot)) for slot in both}
        return frozenset(written)

    # ------------------------------------------------------------------ names and checks
    def fields(self, names: Sequence[str] | None = None, *, overlap: bool = False) -> list[DomainField]:
        """The fields ``names`` names, in order (``None``: all); refuses unknown names and, unless ``overlap``,
        the same name twice and a scale with one object's value of the same kind (:func:`select_fields`)."""
        writes = None if overlap else self.writes
        self._refuse_unmeant(names)
        return select_fields(self._fields, names, self.owner, writes=writes, kinds=self._kinds)

    def checked(
        self, values: object, mask: object, what: str, *, overlap: bool = False
    ) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
        """``values`` (name -> float64 tensor ``[nsim, *value_shape]``) checked by
        :func:`~torchtasks.domain.check_domain_values` for the simulations of ``mask`` (bool ``[nsim]``; None: all),
        as numpy rows of those simulations, with their ids (None: all)."""
        writes = None if overlap else self.writes
        nsim = self.batch.nsim
        self._refuse_unmeant(list(values) if isinstance(values, Mapping) else None)
        mask = check_domain_values(
            self._fields, values, mask, torch.Size([nsim]), self.owner, what=what, writes=writes, kinds=self._kinds
        )
        ids = np.flatnonzero(mask.numpy())
        ids = None if ids.size == nsim else ids
        rows = {}
        for name, value in values.items():
            array = value.numpy(force=True)
            rows[name] = array if ids is None else array[ids]
        return rows, ids

    def _refuse_unmeant(self, names: object) -> None:
        """Refuse a kind's field of an object the kind is not meant for (``actuator_kp`` of a motor), saying which
        objects the kind is offered for and which fields the object has; other names are left to the generic checks."""
        if isinstance(names, (str, bytes)) or not isinstance(names, Sequence):
            return
        for name in names:
            if not isinstance(name, str) or name in self._fields or ":" not in name:
                continue
            stem, obj = name.split(":", 1)
            kind = next((kind for kind in FIELD_KINDS if kind.stem == stem and kind.offered is not None), None)
            if kind is None:
                continue
            has = [
                other
                for other, entry in self.table.items()
                if entry.kind.objects == kind.objects and other.endswith(":" + obj)
            ]
            if has:
                meant = ", ".join(repr(field.split(":", 1)[1]) for field in self._kind_fields[stem]) or "none"
                raise ValueError(
                    f"{self.owner}: {kind.objects} {obj!r} has no domain field {name!r}: {stem} is offered only for "
                    f"the {kind.objects}s whose parameters have its meaning (here: {meant}); {obj!r} has "
                    + ", ".join(has)
                )

    # ------------------------------------------------------------------ writes
    def write(self, rows: Mapping[str, np.ndarray], ids: np.ndarray | None) -> set[FieldKind]:
        """Set the (checked) values ``rows`` of simulations ``ids`` (None: all) and write their kinds' model fields.

        Runs the batch's ``set_const`` once over ``ids`` if a kind written needs it. Returns the kinds written (an
        env field's value is only kept).
        """
        nsim = self.batch.nsim
        for name, value in rows.items():
            if name not in self.values:
                self.values[name] = _nominal_rows(self._fields[name], nsim)
            self.values[name][slice(None) if ids is None else ids] = value
        kinds = {self.table[name].kind for name in rows if name in self.table}
        for kind in kinds:
            self._write_kind(kind, ids)
        if any(kind.set_const for kind in kinds):
            self.batch.set_const(ids)
        return kinds

    def _write_kind(self, kind: FieldKind, ids: np.ndarray | None) -> None:
        """Write ``kind``'s model fields of simulations ``ids`` from the values: each object's value times the scale."""
        where = slice(None) if ids is None else ids
        nominal = self._nominals[kind.stem]
        count = self.batch.nsim if ids is None else len(ids)
        objects = [
            (self.table[name].slots, self.values[name]) for name in self._kind_fields[kind.stem] if name in self.values
        ]
        scale = self.values.get(kind.stem + SCALE)
        scale = None if scale is None else scale[where][:, None]
        ratio = None
        if objects:
            current = np.broadcast_to(nominal, (count, *nominal.shape)).copy()
            for slots, values in objects:
                current[:, slots] = values[where].reshape(current[:, slots].shape)
            if (
                kind.scaled_with
            ):  # value over nominal per object (1 where the nominal value is 0: nothing offered there)
                ratio = np.divide(current, nominal, out=np.ones_like(current), where=nominal != 0)
            if scale is not None:
                current = current * scale
                ratio = None if ratio is None else ratio * scale
        else:  # the scale alone (the usual draw): every object's nominal value times it
            current = nominal * scale
            ratio = np.broadcast_to(scale, current.shape) if kind.scaled_with else None
        self._put(kind.model_field, kind.column, kind.factor, self._covers[kind.stem], current, ids)
        for k, coupled in enumerate(kind.coupled):
            self._put(coupled.model_field, coupled.column, coupled.factor, self._covers[kind.stem, k], current, ids)
        for name in kind.scaled_with:
            follower = self._followers[name]
            self.batch.expand(name)[where] = follower * ratio.reshape(*ratio.shape, *([1] * (follower.ndim - 1)))

    def _put(
        self,
        model_field: str,
        column: int | None,
        factor: float,
        columns: np.ndarray | None,
        current: np.ndarray,
        ids: np.ndarray | None,
    ) -> None:
        """Write ``factor * current`` (a kind's values ``[len(ids), ...]``) into column ``column`` of ``model_field``'s
        rows of simulations ``ids`` (None: all), in the kind's columns ``columns`` only (None: all)."""
        target = self.batch.expand(model_field)
        target = target if column is None else target[..., column]
        if columns is None:
            target[slice(None) if ids is None else ids] = _times(factor, current)
        elif columns.size:
            rows = np.arange(self.batch.nsim) if ids is None else ids
            target[np.ix_(rows, columns)] = _times(factor, current[:, columns])

    def read(self, names: Sequence[str] | None) -> dict[str, np.ndarray]:
        """Every simulation's current value of each field named (copies; nominal where never set)."""
        nsim = self.batch.nsim
        out = {}
        for field in self.fields(names, overlap=True):
            name = field.name
            value = self.values.get(name)
            out[name] = _nominal_rows(field, nsim) if value is None else value.copy()
        return out

    # ------------------------------------------------------------------ checkpoints
    def saved(self) -> dict[str, torch.Tensor]:
        """The values of every field ever set, as float64 tensors (copies): what a checkpoint keeps."""
        return {name: torch.from_numpy(value.copy()) for name, value in self.values.items()}

    def load(self, saved: Mapping[str, np.ndarray]) -> set[FieldKind]:
        """Make the values those of ``saved`` (checked with ``overlap=True``): fields set now but not saved go back
        to nominal. Writes every simulation's fields of the kinds involved; returns them."""
        dropped = [name for name in self.values if name not in saved]
        nominal = {name: _nominal_rows(self._fields[name], self.batch.nsim) for name in dropped}
        kinds = self.write({**nominal, **saved}, None) if (saved or dropped) else set()
        for name in dropped:
            del self.values[name]
        return kinds
