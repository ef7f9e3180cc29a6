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

__all__ = ["DomainEnv", "DomainField", "check_field_name", "check_in_field"]


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
