"""The domain fields of an env: the physics values it can give each of its envs, named, with their allowed range.

An env with per-env physics (:class:`~torchtasks.envs.BatchedMujocoEnv`) describes each value it can vary per
env as a :class:`DomainField` (``"body_mass:torso"``, ``"geom_friction_scale"``, ``"gravity"``, ...) and
offers the three methods of :class:`DomainEnv`. A :class:`~torchtasks.transforms.DomainRandomization` reads
the fields to check its distributions (:func:`check_in_field`: a mass must stay above 0, a friction at or
above 0) and writes the values it draws through :meth:`DomainEnv.set_domain`.

Names: ``"<field>:<object>"`` for one object's value (``"body_mass:torso"``), ``"<field>_scale"`` for a
factor on every object's nominal value (``"body_mass_scale"``), a bare name for a global value
(``"gravity"``). A name holds neither ``"."`` nor ``"/"``: targets and entries use them as separators.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
import torch

from torchtasks._checks import check_tensor, did_you_mean

__all__ = ["DomainEnv", "DomainField", "check_domain_values", "check_field_name", "check_in_field", "select_fields"]


class DomainField(NamedTuple):
    """A physics value an env can give each of its envs: its name, shape, nominal value and allowed range.

    Example:
        >>> import math, torch
        >>> mass = DomainField("body_mass:torso", torch.Size([]), torch.tensor(3.5, dtype=torch.float64),
        ...                    0.0, math.inf, True, ("body_mass", "body_inertia"), True, "mass of body 'torso' (kg)")
        >>> mass.rule
        'in (0.0, inf)'
    """

    #: the name users write (``"body_mass:torso"``)
    name: str
    #: the shape of one env's value (``()`` for a mass, ``(3,)`` for gravity)
    value_shape: torch.Size
    #: the model's value (float64, ``value_shape``); 1.0 for a scale
    nominal: torch.Tensor
    #: the smallest allowed value (excluded when ``low_open``)
    low: float
    #: the largest allowed value (included; ``inf`` for none)
    high: float
    #: whether ``low`` itself is refused (a mass must be > 0)
    low_open: bool
    #: the model fields a value writes (``("body_mass", "body_inertia")``)
    model_fields: tuple[str, ...]
    #: whether a written value needs the model's derived constants recomputed (``mj_setConst``)
    set_const: bool
    #: one line for listings and messages
    description: str
    #: whether only whole numbers are allowed (a delay in steps); the values stay float64, a draw needs ``roundint``
    integer: bool = False

    @property
    def rule(self) -> str:
        """The allowed values as text: ``"in (0.0, inf)"``, ``"in [0.0, inf)"``, ``"finite"``, ``"integer in [0, 3]"``.

        Example:
            >>> import torch
            >>> zero = torch.tensor(0.0, dtype=torch.float64)
            >>> DomainField("delay", torch.Size([]), zero, 0.0, 3.0, False, (), False, "delay (steps)", True).rule
            'integer in [0, 3]'
        """
        prefix = "integer " if self.integer else ""
        if self.low == -math.inf and self.high == math.inf:
            return "integer" if self.integer else "finite"
        # an integer field's finite bounds are whole numbers: shown as such
        low, high = (int(b) if self.integer and math.isfinite(b) else b for b in (self.low, self.high))
        right = "]" if math.isfinite(self.high) else ")"
        return f"{prefix}in {'(' if self.low_open else '['}{low}, {high}{right}"

    def allows(self, values: torch.Tensor) -> torch.Tensor:
        """Elementwise: whether each value is finite, in the field's range and, for an integer field, a whole number
        (a bool tensor of ``values``' shape)."""
        values = values.to(torch.float64)
        above = values > self.low if self.low_open else values >= self.low
        allowed = torch.isfinite(values) & above & (values <= self.high)
        return allowed & (values == torch.round(values)) if self.integer else allowed


def check_field_name(name: str) -> str:
    """Return ``name``; raise ``ValueError`` if it is empty or holds ``"."`` or ``"/"`` (separators elsewhere)."""
    if not isinstance(name, str) or not name or "." in name or "/" in name:
        raise ValueError(f"a domain field's name must be a non-empty string without '.' or '/', got {name!r}")
    return name


def check_in_field(
    field: DomainField,
    lowest: torch.Tensor,
    highest: torch.Tensor,
    what: str,
    remedy: str = "narrow the distribution or clip it (clip_lo, clip_up)",
) -> None:
    """Refuse a range of values ``[lowest, highest]`` (elementwise) that leaves ``field``'s allowed range.

    Args:
        field: the env's field.
        lowest: the smallest value that can be written, per element (broadcastable to ``field.value_shape``, or
            with leading dims, e.g. one row per env or per level); ``-inf`` for an unbounded distribution.
        highest: the largest one, likewise.
        what: who would write the values, for the message (``"NormalDomainParam('body_mass:torso')"``).
        remedy: what to do about it, for the message.

    Example:
        >>> import math, torch
        >>> friction = DomainField("geom_friction:floor", torch.Size([]), torch.tensor(1.0, dtype=torch.float64),
        ...                        0.0, math.inf, False, ("geom_friction",), False, "sliding friction of geom 'floor'")
        >>> check_in_field(friction, torch.tensor(0.0), torch.tensor(2.0), "a uniform draw")
        >>> try:
        ...     check_in_field(friction, torch.tensor(-0.5), torch.tensor(2.0), "a uniform draw")
        ... except ValueError as error:
        ...     print(str(error).split(" (")[0])
        a uniform draw can write -0.5 into 'geom_friction:floor'
    """
    lowest = torch.as_tensor(lowest, dtype=torch.float64).detach().cpu()
    highest = torch.as_tensor(highest, dtype=torch.float64).detach().cpu()
    for values in (lowest, highest):
        bad = ~field.allows(values) & ~(torch.isinf(values) & (values < 0) & (field.low == -math.inf))
        bad &= ~(torch.isinf(values) & (values > 0) & (field.high == math.inf))
        if bool(bad.any()):
            value = values[bad].flatten()[0].item()
            raise ValueError(
                f"{what} can write {value} into {field.name!r} ({field.description}), which must be {field.rule}; "
                + remedy
            )


def select_fields(
    table: Mapping[str, DomainField],
    names: Sequence[str] | None,
    owner: str,
    *,
    writes: Mapping[str, frozenset] | None = None,
    kinds: str = "",
    what: str = "names",
) -> list[DomainField]:
    """The fields of ``table`` that ``names`` names, in order (``None``: all): what ``domain_fields`` answers.

    Refuses a ``names`` that is not a sequence (``TypeError``), an unknown name (the closest ones, the ``kinds`` of
    names the env offers and how many fields it has), a name twice, and, with ``writes`` (``name -> the model values
    it writes``, e.g. ``(model field, object)`` pairs), two names writing a value in common.

    Args:
        table: the env's fields by name.
        names: the names asked for; ``None``: every field.
        owner: who asks, for the messages (``"BatchedMujocoEnv(Hopper-v5)"``).
        writes: what each field writes, to refuse two that overlap; ``None``: overlaps are allowed.
        kinds: a short list of the kinds of names, for the message of an unknown one.
        what: what ``names`` are, for the messages (``"names"``, ``"values"``).

    Example:
        >>> import math, torch
        >>> nominal = torch.tensor(1.0, dtype=torch.float64)
        >>> table = {"mass": DomainField("mass", torch.Size([]), nominal, 0.0, math.inf, True, (), False, "mass")}
        >>> [field.name for field in select_fields(table, ["mass"], "MyEnv")]
        ['mass']
        >>> try:
        ...     select_fields(table, ["mas"], "MyEnv")
        ... except ValueError as error:
        ...     print(str(error).split(" (")[0])
        MyEnv: unknown domain field 'mas' in names; did you mean 'mass'?
    """
    if names is None:
        return list(table.values())
    if isinstance(names, (str, bytes)) or not isinstance(names, Sequence):
        raise TypeError(f"{owner}: {what} must be a sequence of domain field names, got {names!r}")
    names = list(names)
    for name in names:
        if name not in table:
            listed = f"kinds: {kinds}; " if kinds else ""
            raise ValueError(
                f"{owner}: unknown domain field {name!r} in {what}{did_you_mean(str(name), list(table), n=3)} "
                f"({listed}env.domain_fields() lists all {len(table)} fields of this env)"
            )
    for i, name in enumerate(names):
        if name in names[:i]:
            raise ValueError(f"{owner}: the domain field {name!r} is named twice in {names}")
        for other in names[:i] if writes is not None else ():
            common = writes[name] & writes[other]
            if common:
                fields = sorted({str(item[0]) if isinstance(item, tuple) else str(item) for item in common})
                raise ValueError(
                    f"{owner}: {other!r} and {name!r} both write {', '.join(fields)} of the same objects; name one of "
                    "them (a scale and one object's value are not drawn together)"
                )
    return [table[name] for name in names]


def check_domain_values(
    table: Mapping[str, DomainField],
    values: object,
    mask: object,
    batch: torch.Size,
    owner: str,
    *,
    what: str = "values",
    writes: Mapping[str, frozenset] | None = None,
    kinds: str = "",
) -> torch.Tensor:
    """Check what ``set_domain`` received (or a checkpoint holds); return the mask (bool ``batch``, all True for None).

    ``values`` must map names of ``table`` (checked by :func:`select_fields` with ``writes`` and ``kinds``) to float64
    tensors ``[*batch, *value_shape]``, finite, in the field's range and whole numbers for an integer field in the
    envs of ``mask`` (the other rows are ignored). A wrong type or dtype is a ``TypeError``; a wrong shape or value a
    ``ValueError`` naming the field, the env and the value. A host check: ``set_domain`` runs at resets and draws,
    not in every step's tensor code.

    Example:
        >>> import math, torch
        >>> nominal = torch.tensor(1.0, dtype=torch.float64)
        >>> table = {"mass": DomainField("mass", torch.Size([]), nominal, 0.0, math.inf, True, (), False, "mass (kg)")}
        >>> masses = torch.tensor([2.0, 0.0], dtype=torch.float64)
        >>> check_domain_values(table, {"mass": masses}, torch.tensor([True, False]), torch.Size([2]), "MyEnv").tolist()
        [True, False]
        >>> try:
        ...     check_domain_values(table, {"mass": masses}, None, torch.Size([2]), "MyEnv")
        ... except ValueError as error:
        ...     print(error)
        MyEnv: values['mass'] of env 1 is 0.0, but 'mass' (mass (kg)) must be in (0.0, inf)
    """
    if not isinstance(values, Mapping):
        raise TypeError(f"{owner}: {what} must be a mapping of field names to tensors, got {values!r}")
    if mask is None:
        mask = torch.ones(batch, dtype=torch.bool)
    elif not (isinstance(mask, torch.Tensor) and mask.dtype == torch.bool and mask.shape == batch):
        expected_mask = f"a bool tensor of shape {list(batch)} or None"
        check_tensor(mask, torch.bool, batch, f"{owner}.set_domain: mask", expected_mask, " (the env's batch)")
    select_fields(table, list(values), owner, writes=writes, kinds=kinds, what=what)
    # numpy on the host: a few microseconds per field, where torch's small-tensor ops cost tens (this runs at resets);
    # every row in range is the common case, checked in a few operations; the rows of the mask only on a failure
    rows = None
    for name, value in values.items():
        field = table[name]
        shape = (*batch, *field.value_shape)
        if not (isinstance(value, torch.Tensor) and value.dtype == torch.float64 and value.shape == shape):
            expected = f"a float64 tensor of shape {list(shape)} ([*batch, *value_shape])"
            check_tensor(value, torch.float64, shape, f"{owner}: {what}[{name!r}]", expected)
        flat = value.numpy(force=True).reshape(batch.numel(), -1)
        # NaN fails both comparisons; an infinite value fails the finite bound or isfinite
        above = flat > field.low if field.low_open else flat >= field.low
        allowed = above & (flat <= field.high)
        if field.integer:
            allowed &= flat == np.round(flat)
        if not (math.isfinite(field.low) and math.isfinite(field.high)):
            allowed &= np.isfinite(flat)
        if allowed.all():
            continue
        rows = mask.numpy(force=True).reshape(-1) if rows is None else rows
        bad = rows & ~allowed.all(axis=1)
        if bad.any():
            env = int(np.flatnonzero(bad)[0])
            shown = flat[env].tolist() if field.value_shape.numel() > 1 else float(flat[env, 0])
            raise ValueError(
                f"{owner}: {what}[{name!r}] of env {env} is {shown}, but {name!r} ({field.description}) must be "
                f"{field.rule}"
            )
    return mask


@runtime_checkable
class DomainEnv(Protocol):
    """What an env with per-env physics offers a :class:`~torchtasks.transforms.DomainRandomization`."""

    def domain_fields(self, names: Sequence[str] | None = None) -> list[DomainField]:
        """The fields ``names`` names, in order (``None``: every field of the env).

        Raises ``ValueError`` for an unknown name (listing the close ones and saying where the full list is) and for
        two names that write the same model values (``"body_mass_scale"`` with ``"body_mass:torso"``).
        """
        ...

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give the envs of ``mask`` (bool ``[num_envs]``; ``None``: all) the values ``values[name][i]``.

        Each value is a float64 tensor ``[num_envs, *value_shape]``; the rows of envs outside ``mask`` are ignored.
        The values apply from the envs' next reset or step on; their derived constants are recomputed for the
        envs written only, and only for fields that need it.
        """
        ...

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's current value of each field (float64 ``[num_envs, *value_shape]``; nominal if never set)."""
        ...
