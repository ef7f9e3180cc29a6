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

import torch

from torchtasks._checks import did_you_mean

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

    @property
    def rule(self) -> str:
        """The allowed range as text: ``"in (0.0, inf)"``, ``"in [0.0, inf)"``, ``"finite"``."""
        if self.low == -math.inf and self.high == math.inf:
            return "finite"
        right = "]" if math.isfinite(self.high) else ")"
        return f"in {'(' if self.low_open else '['}{self.low}, {self.high}{right}"

    def allows(self, values: torch.Tensor) -> torch.Tensor:
        """Elementwise: whether each value is finite and in the field's range (a bool tensor of ``values``' shape)."""
        values = values.to(torch.float64)
        above = values > self.low if self.low_open else values >= self.low
        return torch.isfinite(values) & above & (values <= self.high)


def check_field_name(name: str) -> str:
    """Return ``name``; raise ``ValueError`` if it is empty or holds ``"."`` or ``"/"`` (separators elsewhere)."""
    if not isinstance(name, str) or not name or "." in name or "/" in name:
        raise ValueError(f"a domain field's name must be a non-empty string without '.' or '/', got {name!r}")
    return name


def check_in_field(field: DomainField, lowest: torch.Tensor, highest: torch.Tensor, what: str) -> None:
    """Refuse a range of values ``[lowest, highest]`` (elementwise) that leaves ``field``'s allowed range.

    Args:
        field: the env's field.
        lowest: the smallest value that can be written, per element (broadcastable to ``field.value_shape``, or
            with leading dims, e.g. one row per env or per level); ``-inf`` for an unbounded distribution.
        highest: the largest one, likewise.
        what: who would write the values, for the message (``"NormalDomainParam('body_mass:torso')"``).

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
                "narrow the distribution or clip it (clip_lo, clip_up)"
            )


def select_fields(
    table: Mapping[str, DomainField],
    names: Sequence[str] | None,
    owner: str,
    writes: Mapping[str, frozenset] | None = None,
) -> list[DomainField]:
    """The fields of ``table`` that ``names`` names, in order (``None``: all): what ``domain_fields`` answers.

    Refuses a name that is not a string, an unknown name (the closest one and how many there are), a name twice,
    and, with ``writes`` (``name -> the model values it writes``), two names writing a value in common.

    Example:
        >>> import math, torch
        >>> nominal = torch.tensor(1.0, dtype=torch.float64)
        >>> table = {"mass": DomainField("mass", torch.Size([]), nominal, 0.0, math.inf, True, (), False, "mass")}
        >>> [field.name for field in select_fields(table, ["mass"], "MyEnv")]
        ['mass']
        >>> try:
        ...     select_fields(table, ["mas"], "MyEnv")
        ... except ValueError as error:
        ...     print(str(error).split(" The")[0])
        MyEnv: unknown domain field 'mas'; did you mean 'mass'?
    """
    if names is None:
        return list(table.values())
    if isinstance(names, (str, bytes)) or not isinstance(names, Sequence):
        raise TypeError(f"{owner}: names must be a sequence of domain field names, got {names!r}")
    listed = list(table)
    for name in names:
        if not isinstance(name, str):
            raise TypeError(f"{owner}: a domain field name must be a string, got {name!r}")
        if name not in table:
            shown = listed if len(listed) <= 12 else [*listed[:12], f"... ({len(listed)} in all)"]
            raise ValueError(
                f"{owner}: unknown domain field {name!r}{did_you_mean(name, listed) or '.'} The env's fields: {shown} "
                "(env.domain_fields() lists them)"
            )
    if len(set(names)) < len(names):
        raise ValueError(f"{owner}: a domain field is named twice in {list(names)}")
    for i, first in enumerate(names):
        for second in names[i + 1 :]:
            if writes is not None and writes[first] & writes[second]:
                raise ValueError(
                    f"{owner}: the domain fields {first!r} and {second!r} write the same model values: give one of them"
                )
    return [table[name] for name in names]


def check_domain_values(
    fields: Mapping[str, DomainField],
    values: Mapping[str, torch.Tensor],
    mask: torch.Tensor | None,
    batch: torch.Size,
    owner: str,
) -> torch.Tensor:
    """Check what ``set_domain`` received; return the mask (bool ``batch``, all True for ``None``).

    Each value must be a float64 tensor ``[*batch, *value_shape]`` of a known field, finite and in the field's range
    in the envs of ``mask``. A host check: ``set_domain`` runs at resets and draws, not in every step's tensor code.
    """
    if not isinstance(values, Mapping):
        raise TypeError(f"{owner}.set_domain: values must be a mapping of field name -> tensor, got {values!r}")
    if mask is None:
        mask = torch.ones(batch, dtype=torch.bool)
    elif not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool or mask.shape != batch:
        got = f"{mask.dtype} {list(mask.shape)}" if isinstance(mask, torch.Tensor) else repr(mask)
        raise ValueError(f"{owner}.set_domain: mask must be a bool tensor of shape {list(batch)}, got {got}")
    select_fields(fields, list(values), f"{owner}.set_domain")
    for name, value in values.items():
        field = fields[name]
        shape = [*batch, *field.value_shape]
        if not isinstance(value, torch.Tensor) or value.dtype != torch.float64 or list(value.shape) != shape:
            got = f"{value.dtype} {list(value.shape)}" if isinstance(value, torch.Tensor) else repr(value)
            raise ValueError(
                f"{owner}.set_domain: values[{name!r}] must be a float64 tensor of shape {shape}, got {got}"
            )
        rows = mask.to(value.device).reshape(*batch, *([1] * len(field.value_shape))).expand_as(value)
        bad = rows & ~field.allows(value)
        if bool(bad.any()):
            raise ValueError(
                f"{owner}.set_domain: values[{name!r}] holds {value[bad].flatten()[0].item()}, but {name!r} "
                f"({field.description}) must be {field.rule}"
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
