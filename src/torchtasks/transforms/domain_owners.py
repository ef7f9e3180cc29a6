"""The owners of an env's domain fields seen as one :class:`~torchtasks.domain.DomainEnv`: :class:`DomainOwners`.

Domain fields have owners: the base env (a :class:`~torchtasks.envs.BatchedMujocoEnv`'s masses and frictions, a
:class:`~torchtasks.envs.PendulumEnv`'s mass) and the transforms of the env that implement the three
:class:`~torchtasks.domain.DomainEnv` methods themselves (an :class:`~torchtasks.transforms.ObservationNoise`'s
``"observation_noise:<entry>"``). A :class:`~torchtasks.transforms.DomainRandomization` draws for all of them through
one :class:`DomainOwners`: each name goes to the owner that offers it. With the base env as the only owner the
randomization talks to the base env itself (:func:`domain_owners` returns it), so nothing changes for it.

An owning transform comes before the randomization in the env's transforms: TorchRL runs the pre-reset hooks and the
inverse calls last to first, so an owner placed before the randomization sees the values drawn for a reset or a step
in its own hooks of that reset or step, and its specs (the shapes of its fields) are built before the randomization's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torchrl.envs.transforms import Transform

from torchtasks._checks import did_you_mean
from torchtasks.domain import DomainEnv, DomainField, check_domain_values

__all__ = ["DomainOwners", "domain_owners"]


class DomainOwners:
    """Several owners of domain fields as one :class:`~torchtasks.domain.DomainEnv`: each name to its owner.

    Every field name belongs to one owner: a name offered by two owners is refused when the view is made. An
    unknown name is refused with the close names of all owners. ``set_domain`` with values of several owners checks
    all of them first (:func:`~torchtasks.domain.check_domain_values`), so a refused write changes no owner.

    Args:
        owners: the owners, each implementing ``domain_fields``, ``set_domain`` and ``domain_values``.
        labels: one name per owner, for the messages (``"the base env PendulumEnv"``, ``"ObservationNoise"``).
        batch_size: the env's batch (the shape of ``set_domain``'s mask).
        who: who asks, for the messages.

    Example:
        >>> import torch
        >>> from torchtasks.envs import PendulumEnv
        >>> pendulums, others = PendulumEnv(batch_size=[2]), PendulumEnv(batch_size=[2])
        >>> try:  # the same names offered twice
        ...     DomainOwners([pendulums, others], ["the base env", "another"], torch.Size([2]))
        ... except ValueError as error:
        ...     print(str(error).split(":")[1].strip())
        the domain field 'mass' is offered by the base env and by another
    """

    def __init__(
        self,
        owners: Sequence[DomainEnv],
        labels: Sequence[str],
        batch_size: torch.Size,
        who: str = "DomainRandomization",
    ) -> None:
        if len(owners) != len(labels):
            raise ValueError(f"DomainOwners: one label per owner, got {len(owners)} owners and {len(labels)} labels")
        self.owners = tuple(owners)
        self.labels = tuple(labels)
        self.batch_size = torch.Size(batch_size)
        self.who = who
        #: every field by name, and the index of the owner offering it
        self.fields: dict[str, DomainField] = {}
        self.owner_of: dict[str, int] = {}
        for index, owner in enumerate(self.owners):
            for field in owner.domain_fields(None):
                other = self.owner_of.setdefault(field.name, index)
                if other != index:
                    raise ValueError(
                        f"{who}: the domain field {field.name!r} is offered by {self.labels[other]} and by "
                        f"{self.labels[index]}: a field has one owner; rename or remove one of them"
                    )
                self.fields[field.name] = field

    def _groups(self, names: Sequence[str], what: str) -> dict[int, list[str]]:
        """``names`` by the index of their owner, in order; an unknown name is refused with the close names."""
        groups: dict[int, list[str]] = {}
        for name in names:
            index = self.owner_of.get(name) if isinstance(name, str) else None
            if index is None:
                for owner in self.owners:
                    reason = getattr(owner, "absent_field_reason", lambda _: None)(name)
                    if reason is not None:
                        raise ValueError(f"{self.who}: {reason}")
                counts = [sum(1 for i in self.owner_of.values() if i == k) for k in range(len(self.labels))]
                listed = ", ".join(
                    f"{label} ({count} field{'' if count == 1 else 's'})"
                    for label, count in zip(self.labels, counts, strict=True)
                )
                raise ValueError(
                    f"{self.who}: unknown domain field {name!r} in {what}"
                    f"{did_you_mean(str(name), list(self.fields), n=3)} (the owners of domain fields in this env: "
                    f"{listed}; each one's domain_fields() lists its fields)"
                )
            groups.setdefault(index, []).append(name)
        return groups

    def domain_fields(self, names: Sequence[str] | None = None) -> list[DomainField]:
        """The fields ``names`` names, in order (``None``: all), each owner checking its own (overlaps, repeats)."""
        if names is None:
            return list(self.fields.values())
        if isinstance(names, (str, bytes)) or not isinstance(names, Sequence):
            raise TypeError(f"{self.who}: names must be a sequence of domain field names, got {names!r}")
        names = list(names)
        found: dict[str, DomainField] = {}
        for index, group in self._groups(names, "names").items():
            found.update((field.name, field) for field in self.owners[index].domain_fields(group))
        return [found[name] for name in names]

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give each owner its values (see :meth:`~torchtasks.domain.DomainEnv.set_domain`); all checked first when
        they span several owners, so that a refused write changes nothing."""
        if not isinstance(values, Mapping):
            raise TypeError(f"{self.who}: values must be a mapping of field names to tensors, got {values!r}")
        groups = self._groups(list(values), "values")
        if len(groups) > 1:
            check_domain_values(self.fields, values, mask, self.batch_size, self.who)
        for index, group in groups.items():
            self.owners[index].set_domain({name: values[name] for name in group}, mask)

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's current value of each field named (``None``: all), from its owner."""
        names = list(self.fields) if names is None else list(names)
        found: dict[str, torch.Tensor] = {}
        for index, group in self._groups(names, "names").items():
            found.update(self.owners[index].domain_values(group))
        return {name: found[name] for name in names}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({list(self.labels)})"


def domain_owners(
    base: object, transforms: Sequence[Transform], batch_size: torch.Size, who: str = "DomainRandomization"
) -> DomainEnv | None:
    """The owners of domain fields among ``base`` (the base env) and ``transforms`` (the env's transforms before the
    randomization) as one :class:`~torchtasks.domain.DomainEnv`: ``base`` itself when no transform owns fields,
    ``None`` when nothing does, else a :class:`DomainOwners`.

    Example:
        >>> import torch
        >>> from torchtasks.envs import PendulumEnv
        >>> base = PendulumEnv(batch_size=[2])
        >>> domain_owners(base, [], torch.Size([2])) is base
        True
        >>> domain_owners(object(), [], torch.Size([2])) is None
        True
    """
    owned = [t for t in transforms if isinstance(t, DomainEnv)]
    base_owns = isinstance(base, DomainEnv)
    if not owned:
        return base if base_owns else None
    owners = ([base] if base_owns else []) + owned
    labels = ([f"the base env {type(base).__name__}"] if base_owns else []) + [type(t).__name__ for t in owned]
    return DomainOwners(owners, labels, batch_size, who)
