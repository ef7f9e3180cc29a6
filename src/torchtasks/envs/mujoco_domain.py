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

The env may own fields beside the model's (:class:`~torchtasks.envs.BatchedMujocoEnv`'s ``"action_delay"``): given to
:class:`BatchDomain` as ``env_fields``, they are named, checked, kept and saved with the model's, in the same table;
their values write no model field (the env reads them where its own semantics say).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
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

__all__ = ["FIELD_KINDS", "BatchDomain", "FieldKind", "domain_field"]

#: the suffix of a kind's scale field
SCALE = "_scale"


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


#: The field kinds, in the order :meth:`BatchDomain.fields` lists them. ``set_const`` follows
#: ``MjModel._setconst_inputs`` (``body_mass``, ``body_inertia``, ``dof_armature``, ``actuator_gear``; not
#: ``geom_friction``, ``dof_damping``). Gravity needs none: ``mj_setConst`` reads no ``opt`` field (``mjxmacro.h``'s
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


def _objects(model: mujoco.MjModel, kind: FieldKind, nominal: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The objects offered for ``kind``: (name, the columns of the kind's values it covers)."""
    if kind.objects is None:
        return []
    offered = []
    for i in range(getattr(model, _COUNTS[kind.objects])):
        name = getattr(model, kind.objects)(i).name
        if not name and kind.objects == "actuator" and model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT:
            name = model.joint(int(model.actuator_trnid[i, 0])).name  # an unnamed actuator: named by its joint
        if not name or "." in name or "/" in name or (kind.objects == "body" and i == 0):
            continue
        if kind.objects == "joint":
            start = int(model.jnt_dofadr[i])
            slots = np.arange(start, start + _JOINT_DOFS[int(model.jnt_type[i])])
        else:
            slots = np.array([i])
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
        nominal = _kind_values(_model_value(model, kind.model_field), kind)
        common = {"high": math.inf, "model_fields": (kind.model_field, *kind.scaled_with), "set_const": kind.set_const}
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
        if kind.scale_low_open is not None:
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
        #: the model values each field writes: (model field, column of the kind's values); two fields named together
        #: must write none in common
        self.writes = {
            name: frozenset(
                (entry.kind.model_field, int(slot))
                for slot in (
                    range(_kind_values(_model_value(model, entry.kind.model_field), entry.kind).shape[0])
                    if entry.slots is None
                    else entry.slots
                )
            )
            for name, entry in self.table.items()
        }
        self.writes.update({field.name: frozenset({(field.name, 0)}) for field in env_fields})
        self.values: dict[str, np.ndarray] = {}
        #: every field by name: the model's (``table``), then the env's own
        self._fields = {name: entry.field for name, entry in self.table.items()}
        self._fields.update({field.name: field for field in env_fields})
        #: per kind: the model's (nominal) values, the one-object fields, and the model values that follow the kind
        self._nominals = {
            kind.stem: _kind_values(_model_value(model, kind.model_field), kind).copy() for kind in FIELD_KINDS
        }
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

    # ------------------------------------------------------------------ names and checks
    def fields(self, names: Sequence[str] | None = None, *, overlap: bool = False) -> list[DomainField]:
        """The fields ``names`` names, in order (``None``: all); refuses unknown names and, unless ``overlap``,
        the same name twice and a scale with one object's value of the same kind (:func:`select_fields`)."""
        writes = None if overlap else self.writes
        return select_fields(self._fields, names, self.owner, writes=writes, kinds=self._kinds)

    def checked(
        self, values: object, mask: object, what: str, *, overlap: bool = False
    ) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
        """``values`` (name -> float64 tensor ``[nsim, *value_shape]``) checked by
        :func:`~torchtasks.domain.check_domain_values` for the simulations of ``mask`` (bool ``[nsim]``; None: all),
        as numpy rows of those simulations, with their ids (None: all)."""
        writes = None if overlap else self.writes
        nsim = self.batch.nsim
        mask = check_domain_values(
            self._fields, values, mask, torch.Size([nsim]), self.owner, what=what, writes=writes, kinds=self._kinds
        )
        ids = np.flatnonzero(mask.numpy())
        ids = None if ids.size == nsim else ids
        rows = {}
        for name, value in values.items():
            array = value.detach().cpu().numpy()
            rows[name] = array if ids is None else array[ids]
        return rows, ids

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
        _kind_values(self.batch.expand(kind.model_field), kind)[where] = current
        for name in kind.scaled_with:
            follower = self._followers[name]
            self.batch.expand(name)[where] = follower * ratio.reshape(*ratio.shape, *([1] * (follower.ndim - 1)))

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
