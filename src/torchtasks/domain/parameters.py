"""Domain parameters: the distribution each env's value of a physics field is drawn from.

Pyrado's domain parameters (``UniformDomainParam``, ``NormalDomainParam``, ``MultivariateNormalDomainParam``,
``BernoulliDomainParam``) in torch: a :class:`DomainParam` names the env's field it draws for
(``"body_mass:torso"``, see :mod:`torchtasks.domain.fields`), holds its distribution's parameters and its clipping
bounds as float64 buffers (so ``state_dict()``, ``.to()`` and a curriculum's target lookup reach them by name:
``"mean"``, ``"halfspan"``, ``"clip_lo"``, ...) and draws values with a given generator. As in Pyrado, a draw is
clipped to ``[clip_lo, clip_up]`` and then, with ``roundint=True``, rounded.

Every value the parameters can take passes one check, whoever writes it: the constructor, a schedule or level table
(:meth:`DomainParam.check_written_value`) and a loaded checkpoint. Once bound to the env's field
(:meth:`DomainParam.bind_field`), the values a draw can reach (:meth:`DomainParam.support`) must also stay in the
field's allowed range (a mass above 0).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import FLOAT64, as_constant, check_batch_size, check_non_negative_int, check_real_numbers
from torchtasks.domain.fields import DomainField, check_field_name, check_in_field

__all__ = [
    "BernoulliDomainParam",
    "DomainParam",
    "MultivariateNormalDomainParam",
    "NormalDomainParam",
    "UniformDomainParam",
]

Params = Mapping[str, torch.Tensor]

#: values shown whole in messages and reprs up to this many elements
_SHOWN = 8


class DomainParam(CheckedLoad, nn.Module):
    """Base class of the domain parameters: a named field's distribution, its clipping bounds and rounding.

    Subclasses register their distribution's parameters; every buffer named in :attr:`distribution_fields` is a
    float64 tensor of the value shape (:attr:`value_shape`; a covariance ``[d, d]``), or with leading per-env dims
    after :meth:`use_per_env`. Subclasses implement the draw (:meth:`_draw`), the rules of their parameters
    (:meth:`_check_distribution`) and the range a draw can take before clipping (:meth:`_unclipped_support`).

    Args:
        name: the env field the values are drawn for (``"body_mass:torso"``; no ``"."`` or ``"/"``).
        params: the distribution's parameters by buffer name, the first one giving the value shape (its shape).
        clip_lo: the lower clipping bound: a number (every element) or a tensor of the value shape; ``-inf``: none.
        clip_up: the upper clipping bound, likewise; ``inf``: none.
        roundint: round clipped draws to the nearest integer (they stay float64).

    Example:
        >>> import torch
        >>> param = UniformDomainParam("body_mass:torso", mean=3.5, halfspan=0.5, clip_up=3.75)
        >>> [name for name, _ in param.named_buffers()]
        ['mean', 'halfspan', 'clip_lo', 'clip_up']
        >>> param.support()
        (tensor(3., dtype=torch.float64), tensor(3.7500, dtype=torch.float64))
    """

    #: the buffers a schedule or a level table may write, in order (the distribution's parameters, then clipping)
    distribution_fields: ClassVar[tuple[str, ...]] = ()
    #: the parameters that must be finite (every distribution parameter; the clipping bounds may be infinite)
    _finite_fields: ClassVar[tuple[str, ...]] = ()

    def __init__(
        self,
        name: str,
        params: Mapping[str, object],
        *,
        clip_lo: object = -math.inf,
        clip_up: object = math.inf,
        roundint: bool = False,
    ) -> None:
        super().__init__()
        self.name = check_field_name(name)
        if not isinstance(roundint, bool):
            raise TypeError(f"{type(self).__name__}({name!r}): roundint must be a bool, got {roundint!r}")
        self.roundint = roundint
        self._field: DomainField | None = None
        raw = {**params, "clip_lo": clip_lo, "clip_up": clip_up}
        first = self.distribution_fields[0]
        tensors = {first: _as_parameter(raw[first], first, None)}
        self._value_shape = self._value_shape_of(tensors[first])
        device = tensors[first].device
        for key in self.distribution_fields[1:]:
            tensors[key] = _as_parameter(raw[key], key, self._param_shape(key), first).to(device)
        try:
            self._check_params(tensors, None)
        except ValueError as error:
            raise ValueError(f"{type(self).__name__}({name!r}): {error}") from None
        for key in self.distribution_fields:
            self.register_buffer(key, tensors[key])

    # ---------------------------------------------------------------------------- shapes
    @property
    def value_shape(self) -> torch.Size:
        """The shape of one env's value (without per-env leading dims): the first parameter's shape."""
        return self._value_shape

    def _value_shape_of(self, first: torch.Tensor) -> torch.Size:
        """The value shape given by the first parameter (converted by the subclass)."""
        return first.shape

    def parameter_shape(self, name: str) -> torch.Size:
        """The shape of one env's value of the distribution buffer ``name``: the value shape, a covariance's ``[d, d]``.

        Example:
            >>> import torch
            >>> param = MultivariateNormalDomainParam("gravity", [0.0, 0.0, -9.81], torch.eye(3) * 0.01)
            >>> param.parameter_shape("mean"), param.parameter_shape("cov")
            (torch.Size([3]), torch.Size([3, 3]))
        """
        if name not in self.distribution_fields:
            raise ValueError(
                f"{type(self).__name__}.parameter_shape: {name!r} is no distribution buffer; the buffers are "
                f"{list(self.distribution_fields)}"
            )
        return self._param_shape(name)

    def _param_shape(self, name: str) -> torch.Size:
        """The shape of one env's value of the buffer ``name`` (the value shape; a covariance's ``[d, d]``)."""
        return self._value_shape

    def _lead_shape(self) -> torch.Size:
        """The per-env leading dims of the buffers (``()`` for one distribution shared by every env)."""
        return _lead(self._buffers[self.distribution_fields[0]].shape, self._param_shape(self.distribution_fields[0]))

    def _check_shapes(self, shapes: Mapping[str, torch.Size]) -> None:
        """Refuse buffer shapes that are not ``[*B, *param shape]`` with one ``B`` for every buffer."""
        leads = {}
        for name, shape in shapes.items():
            own = self._param_shape(name)
            if len(shape) < len(own) or shape[len(shape) - len(own) :] != own:
                raise ValueError(
                    f"{name} must have shape {list(own)} or [*B{''.join(f', {n}' for n in own)}] (one row per env), "
                    f"got {list(shape)}"
                )
            leads[name] = _lead(shape, own)
        if len(set(leads.values())) > 1:
            listed = ", ".join(f"{name}: {list(lead)}" for name, lead in leads.items())
            raise ValueError(f"the buffers must share their per-env leading dims, got {listed}")

    # ----------------------------------------------------------------------- the one check
    def _check_params(self, params: Params, field: DomainField | None) -> None:
        """Raise ``ValueError`` unless ``params`` (every buffer, broadcastable) is a distribution this class accepts.

        The constructor, :meth:`check_written_value` and a load run this one check: no NaN, finite distribution
        parameters, the subclass's rules (a halfspan >= 0, ...), ``clip_lo <= clip_up``, and, with ``field``,
        every value a draw can take inside the field's allowed range.
        """
        for name in self.distribution_fields:
            values = params[name]
            _require(~torch.isnan(values), "not be NaN", name, values)
            if name in self._finite_fields:
                _require(torch.isfinite(values), "be finite", name, values)
        self._check_distribution(params)
        low, up = params["clip_lo"], params["clip_up"]
        _require(low < math.inf, "be below inf (every draw would be inf)", "clip_lo", low)
        _require(up > -math.inf, "be above -inf (every draw would be -inf)", "clip_up", up)
        ordered = low <= up
        if not bool(ordered.all()):
            index = _first(~ordered)
            low_b, up_b = torch.broadcast_to(low, ordered.shape), torch.broadcast_to(up, ordered.shape)
            raise ValueError(
                f"clip_lo must not exceed clip_up, got clip_lo={low_b[index].item()} > clip_up={up_b[index].item()}"
                + (f" at index {list(index)}" if index else "")
            )
        if field is not None:
            check_in_field(field, *self._support_of(params), repr(self))

    def _check_distribution(self, params: Params) -> None:
        """Raise ``ValueError`` if the distribution's own parameters break the subclass's rules."""
        raise NotImplementedError

    # ------------------------------------------------------------------------------ draws
    def sample(self, num: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """Draw ``num`` values: a float64 tensor ``[num, *value_shape]`` on the buffers' device.

        The numbers come from ``generator`` (a CPU generator; ``None``: torch's global one) in one call of a size
        that depends on ``num`` only, so the stream it leaves does not depend on the values drawn. Draws are then
        clipped to ``[clip_lo, clip_up]`` and, with ``roundint``, rounded to the nearest integer (half to even)
        and kept float64, since the env's fields are floats (Pyrado casts rounded draws to int32).
        With per-env parameters (:meth:`use_per_env`) ``num`` must be the number of envs and value ``i`` is drawn
        from env ``i``'s parameters (envs in row-major order).

        Example:
            >>> import torch
            >>> param = NormalDomainParam("gravity", mean=[0.0, 0.0, -9.81], std=[0.0, 0.0, 0.5])
            >>> values = param.sample(4, torch.Generator().manual_seed(0))
            >>> values.shape, values[:, :2].abs().max().item()
            (torch.Size([4, 3]), 0.0)
        """
        if type(num) is not int or num < 0:  # the message is built only for a bad num (this runs at resets)
            num = check_non_negative_int(num, f"{type(self).__name__}.sample: num")
        lead = self._lead_shape()
        if lead and num != lead.numel():
            raise ValueError(
                f"{type(self).__name__}.sample: num must be the number of envs, {lead.numel()} (per-env parameters "
                f"of batch {list(lead)}), got {num}"
            )
        params = {
            name: buffer.reshape(num, *self._param_shape(name)) if lead else buffer
            for name, buffer in ((name, self._buffers[name]) for name in self.distribution_fields)
        }
        values = self._draw(params, num, generator)
        values = torch.clamp(values, params["clip_lo"], params["clip_up"])
        return torch.round(values) if self.roundint else values

    def _draw(self, params: Params, num: int, generator: torch.Generator | None) -> torch.Tensor:
        """``num`` unclipped draws ``[num, *value_shape]`` from ``params`` (rows ``[num, ...]`` or shared)."""
        raise NotImplementedError

    def _noise(
        self, sampler: Callable[..., torch.Tensor], num: int, generator: torch.Generator | None, device: torch.device
    ) -> torch.Tensor:
        """One call of ``sampler`` (``torch.rand``/``torch.randn``) for ``[num, *value_shape]`` on the CPU, moved."""
        shape = (num, *self._value_shape)
        noise = sampler(shape, generator=generator, dtype=FLOAT64, device="cpu")
        return noise if device.type == "cpu" else noise.to(device)

    # ---------------------------------------------------------------------------- support
    def support(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The smallest and the largest value a draw can take, elementwise: ``[*per-env dims, *value_shape]`` each.

        The distribution's range (uniform: ``mean -/+ halfspan``; normal: unbounded; Bernoulli: the two values),
        clipped, then rounded with ``roundint``.

        Example:
            >>> param = NormalDomainParam("dof_damping:hip", mean=1.0, std=0.2, clip_lo=0.0)
            >>> param.support()
            (tensor(0., dtype=torch.float64), tensor(inf, dtype=torch.float64))
        """
        return self._support_of({name: self._buffers[name] for name in self.distribution_fields})

    def _support_of(self, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        low, high = self._unclipped_support(params)
        clip = params["clip_lo"], params["clip_up"]
        low, high = torch.clamp(low, *clip), torch.clamp(high, *clip)
        return (torch.round(low), torch.round(high)) if self.roundint else (low, high)

    def _unclipped_support(self, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        """The range of the unclipped draws (broadcast over the parameters' shapes)."""
        raise NotImplementedError

    # ---------------------------------------------------------------------------- per env
    def use_per_env(self, batch: torch.Size) -> None:
        """Give every env of ``batch`` its own parameters: each buffer becomes ``[*batch, *its shape]``.

        Every env starts from the current values; nothing changes if the buffers already have that shape. Then
        :meth:`sample` draws value ``i`` from env ``i``'s row (a level table writes rows of these buffers).

        Raises:
            ValueError: a buffer is already per-env with another batch.
            TypeError: ``batch`` is not a sequence of non-negative ints.

        Example:
            >>> import torch
            >>> param = UniformDomainParam("geom_friction:floor", mean=1.0, halfspan=0.0)
            >>> param.use_per_env(torch.Size([3]))
            >>> param.mean[2] = 2.0
            >>> param.sample(3).tolist()
            [1.0, 1.0, 2.0]
        """
        batch = check_batch_size(batch, f"{type(self).__name__}.use_per_env: batch")
        for name in self.distribution_fields:
            own, shape = self._param_shape(name), self._buffers[name].shape
            if shape not in (own, batch + own):
                raise ValueError(
                    f"{type(self).__name__}.use_per_env: the buffer {name!r} has shape {list(shape)}, which is neither "
                    f"shared {list(own)} nor the requested per-env shape {list(batch + own)} (batch {list(batch)})"
                )
        for name in self.distribution_fields:
            buffer = self._buffers[name]
            if buffer.shape != batch + self._param_shape(name):
                self._buffers[name] = buffer.expand(batch + self._param_shape(name)).clone()

    # --------------------------------------------------------------------- env field, writes
    def bind_field(self, field: DomainField) -> None:
        """Check the parameter against the env's ``field`` it draws for and remember it for later checks.

        Raises ``ValueError`` if the value shapes differ, the field is an integer one and the parameter does not round
        (``roundint=False``), or a draw can leave the field's allowed range
        (:func:`~torchtasks.domain.fields.check_in_field`).

        Example:
            >>> import math, torch
            >>> from torchtasks.domain import DomainField
            >>> mass = DomainField("body_mass:torso", torch.Size([]), torch.tensor(3.5, dtype=torch.float64),
            ...                    0.0, math.inf, True, ("body_mass",), True, "mass of body 'torso' (kg)")
            >>> UniformDomainParam("body_mass:torso", mean=3.5, halfspan=1.0).bind_field(mass)
            >>> try:
            ...     UniformDomainParam("body_mass:torso", mean=3.5, halfspan=4.0).bind_field(mass)
            ... except ValueError as error:
            ...     print(str(error).split(" (")[0])
            UniformDomainParam('body_mass:torso', mean=3.5, halfspan=4.0) can write -0.5 into 'body_mass:torso'
        """
        if not isinstance(field, DomainField):
            raise TypeError(f"{self!r}.bind_field: field must be a DomainField, got {type(field).__name__}")
        if field.value_shape != self._value_shape:
            raise ValueError(
                f"{self!r} draws values of shape {list(self._value_shape)}, but the field {field.name!r} "
                f"({field.description}) has values of shape {list(field.value_shape)}"
            )
        if field.integer and not self.roundint:
            raise ValueError(
                f"{self!r} draws for the integer field {field.name!r} ({field.description}, {field.rule}) without "
                "rounding; pass roundint=True"
            )
        check_in_field(field, *self.support(), repr(self))
        self._field = field

    def check_written_value(self, buffer: str, value: torch.Tensor, label: str) -> None:
        """Refuse a value a writer (a schedule, a level table) may put into ``buffer`` that the parameter refuses.

        ``value``: of the buffer's shape (its new content), of one env's row (it may go into any env), or rows
        ``[n, *row]`` (each may go into any env). It is checked with the other buffers' current values by the
        constructor's rules and, once a field is bound, against the field's allowed range.

        Example:
            >>> import torch
            >>> param = UniformDomainParam("body_mass:torso", mean=3.5, halfspan=0.0)
            >>> param.check_written_value("halfspan", torch.tensor([0.5, 1.0]), "a level table")
            >>> try:
            ...     param.check_written_value("halfspan", torch.tensor(-0.5), "a schedule")
            ... except ValueError as error:
            ...     print(error)
            a schedule can write -0.5 into UniformDomainParam('body_mass:torso', mean=3.5, halfspan=0.0)'s halfspan, \
which it refuses: halfspan must be >= 0, got -0.5
        """
        self.check_written_values({buffer: value}, label)

    def check_written_values(self, values: Mapping[str, torch.Tensor], label: str, *, as_rows: bool = False) -> None:
        """Refuse values that writers put into several buffers TOGETHER (a schedule of the mean and one of the halfspan,
        two level tables) that the parameter refuses: each value as in :meth:`check_written_value`, and values given
        as rows ``[n, *row]`` are taken together row by row (row ``k`` of every buffer is one combination), with the
        unwritten buffers' current values. ``as_rows=True``: every value is rows ``[n, *row]``, each checked against
        every env, also where ``[n, *row]`` is the shape of a per-env buffer (``n`` equal to the number of envs).

        Example:
            >>> import torch
            >>> import math
            >>> from torchtasks.domain import DomainField
            >>> nominal = torch.tensor(3.5, dtype=torch.float64)
            >>> mass = DomainField("body_mass:torso", torch.Size([]), nominal, 0.0, math.inf, True, (), True, "mass")
            >>> param = UniformDomainParam("body_mass:torso", mean=3.5, halfspan=0.0)
            >>> param.bind_field(mass)
            >>> rows = {"mean": torch.tensor([3.5, 1.0]), "halfspan": torch.tensor([0.5, 2.0])}  # level 1: 1.0 +- 2.0
            >>> param.check_written_value("mean", rows["mean"], "a table")  # each alone is fine
            >>> param.check_written_value("halfspan", rows["halfspan"], "a table")
            >>> try:
            ...     param.check_written_values(rows, "two level tables")  # together they reach a mass of -1
            ... except ValueError as error:
            ...     print(str(error).split(" together")[0])
            two level tables can write mean=[3.5, 1.0] and halfspan=[0.5, 2.0]
        """
        if not isinstance(values, Mapping) or not values:
            raise TypeError(f"{label}: values must be a non-empty mapping of buffer name -> tensor, got {values!r}")
        params = {name: self._buffers[name] for name in self.distribution_fields}
        rows = set()
        for buffer, value in values.items():
            if buffer not in self.distribution_fields:
                raise ValueError(
                    f"{label}: {self!r} has no distribution buffer {buffer!r}; it has {list(self.distribution_fields)}"
                )
            if not isinstance(value, torch.Tensor):
                raise TypeError(f"{label}: the value written into {self!r}'s {buffer} must be a tensor, got {value!r}")
            check_real_numbers(value, f"{label}: the value written into {self!r}'s {buffer}")
            own = self._buffers[buffer]
            row = self._param_shape(buffer)
            written = value.detach().to(dtype=FLOAT64, device=own.device)
            if as_rows or value.shape not in (own.shape, row):
                if value.dim() == 0 or value.shape[1:] != row:
                    shapes = "" if as_rows else f"the buffer's shape {list(own.shape)}, one env's shape {list(row)} or "
                    raise ValueError(
                        f"{label}: the value written into {self!r}'s {buffer} must have {shapes}"
                        f"rows [n{''.join(f', {n}' for n in row)}], got {list(value.shape)}"
                    )
                rows.add(value.shape[0])
                lead = _lead(own.shape, row)
                written = written.reshape(value.shape[0], *(1,) * len(lead), *row)  # each row against every env
            params[buffer] = written
        if len(rows) > 1:
            raise ValueError(f"{label}: values written together must have the same number of rows, got {sorted(rows)}")
        try:
            self._check_params(params, self._field)
        except ValueError as error:
            if len(values) == 1:
                ((buffer, value),) = values.items()
                shown = f"{_show(value)} into {self!r}'s {buffer}"
            else:
                shown = " and ".join(f"{buffer}={_show(value)}" for buffer, value in values.items())
                shown += f" together into {self!r}"
            raise ValueError(f"{label} can write {shown}, which it refuses: {error}") from None

    # ------------------------------------------------------------------------ checkpoints
    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        saved = {
            name: state_dict[prefix + name].shape
            for name in self.distribution_fields
            if isinstance(state_dict.get(prefix + name), torch.Tensor)
        }
        try:
            self._check_shapes(saved)
        except ValueError as error:
            raise ValueError(f"{type(self).__name__}({self.name!r}).load_state_dict: {error}") from None

    def _prepare_load(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        # a saved buffer of one layout (shared or per-env) loads into the other: the buffer takes the saved shape
        for name in self.distribution_fields:
            saved, own = state_dict.get(prefix + name), self._buffers[name]
            if isinstance(saved, torch.Tensor) and saved.shape != own.shape:
                self._buffers[name] = torch.empty(saved.shape, dtype=own.dtype, device=own.device)

    def _check_loaded(self) -> None:
        """Refuse a loaded state the constructor would refuse, or whose draws leave the bound field."""
        try:
            self._check_shapes({name: self._buffers[name].shape for name in self.distribution_fields})
            self._check_params({name: self._buffers[name] for name in self.distribution_fields}, self._field)
        except ValueError as error:
            raise ValueError(f"{type(self).__name__}({self.name!r}).load_state_dict: {error}") from None

    # ------------------------------------------------------------------------------ repr
    def __repr__(self) -> str:
        lead = self._lead_shape()

        def entry(name: str) -> str:
            return (
                f"{name}=<per env {list(self._buffers[name].shape)}>"
                if lead
                else f"{name}={_show(self._buffers[name])}"
            )

        shown = [entry(name) for name in self.distribution_fields if name not in ("clip_lo", "clip_up")]
        if not bool((self._buffers["clip_lo"] == -math.inf).all()):
            shown.append(entry("clip_lo"))
        if not bool((self._buffers["clip_up"] == math.inf).all()):
            shown.append(entry("clip_up"))
        if self.roundint:
            shown.append("roundint=True")
        return f"{type(self).__name__}({self.name!r}, {', '.join(shown)})"


class UniformDomainParam(DomainParam):
    """Values drawn uniformly from ``[mean - halfspan, mean + halfspan]``, clipped, optionally rounded.

    ``halfspan = 0`` draws ``mean`` (a curriculum can start from the nominal value and widen the range).
    Pyrado name: ``UniformDomainParam``.

    Args:
        name: the env field (``"body_mass:torso"``).
        mean: the centre; its shape is the value shape.
        halfspan: half the width, >= 0: a number (every element) or a tensor of the value shape.
        clip_lo: the lower clipping bound (number or tensor of the value shape).
        clip_up: the upper clipping bound (likewise).
        roundint: round the clipped draws (kept float64).

    Example:
        >>> import torch
        >>> param = UniformDomainParam("body_mass:torso", mean=3.5, halfspan=0.5)
        >>> param
        UniformDomainParam('body_mass:torso', mean=3.5, halfspan=0.5)
        >>> values = param.sample(1000, torch.Generator().manual_seed(0))
        >>> bool(values.min() >= 3.0), bool(values.max() <= 4.0)
        (True, True)
    """

    distribution_fields = ("mean", "halfspan", "clip_lo", "clip_up")
    _finite_fields = ("mean", "halfspan")

    def __init__(
        self,
        name: str,
        mean: object,
        halfspan: object,
        *,
        clip_lo: object = -math.inf,
        clip_up: object = math.inf,
        roundint: bool = False,
    ) -> None:
        super().__init__(
            name, {"mean": mean, "halfspan": halfspan}, clip_lo=clip_lo, clip_up=clip_up, roundint=roundint
        )

    def _check_distribution(self, params: Params) -> None:
        _require(params["halfspan"] >= 0, "be >= 0", "halfspan", params["halfspan"])
        low, high = self._unclipped_support(params)
        _require(torch.isfinite(low), "be finite", "mean - halfspan", low)
        _require(torch.isfinite(high), "be finite", "mean + halfspan", high)

    def _unclipped_support(self, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        return params["mean"] - params["halfspan"], params["mean"] + params["halfspan"]

    def _draw(self, params: Params, num: int, generator: torch.Generator | None) -> torch.Tensor:
        low, high = self._unclipped_support(params)
        return low + self._noise(torch.rand, num, generator, low.device) * (high - low)


class NormalDomainParam(DomainParam):
    """Values drawn from a normal distribution ``N(mean, std**2)`` per element, clipped, optionally rounded.

    ``std = 0`` draws ``mean``. Pyrado name: ``NormalDomainParam``.

    Args:
        name: the env field (``"dof_damping:hip"``).
        mean: the mean; its shape is the value shape.
        std: the standard deviation, >= 0: a number or a tensor of the value shape.
        clip_lo: the lower clipping bound (number or tensor of the value shape).
        clip_up: the upper clipping bound (likewise).
        roundint: round the clipped draws (kept float64).

    Example:
        >>> import torch
        >>> param = NormalDomainParam("geom_friction_scale", mean=1.0, std=0.1, clip_lo=0.5)
        >>> param
        NormalDomainParam('geom_friction_scale', mean=1.0, std=0.1, clip_lo=0.5)
        >>> param.sample(3, torch.Generator().manual_seed(0)).shape
        torch.Size([3])
    """

    distribution_fields = ("mean", "std", "clip_lo", "clip_up")
    _finite_fields = ("mean", "std")

    def __init__(
        self,
        name: str,
        mean: object,
        std: object,
        *,
        clip_lo: object = -math.inf,
        clip_up: object = math.inf,
        roundint: bool = False,
    ) -> None:
        super().__init__(name, {"mean": mean, "std": std}, clip_lo=clip_lo, clip_up=clip_up, roundint=roundint)

    def _check_distribution(self, params: Params) -> None:
        _require(params["std"] >= 0, "be >= 0", "std", params["std"])

    def _unclipped_support(self, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        shape = torch.broadcast_shapes(params["mean"].shape, params["std"].shape)
        return _unbounded(shape, params["mean"].device)

    def _draw(self, params: Params, num: int, generator: torch.Generator | None) -> torch.Tensor:
        mean = params["mean"]
        return mean + params["std"] * self._noise(torch.randn, num, generator, mean.device)


class MultivariateNormalDomainParam(DomainParam):
    """Vectors drawn from ``N(mean, cov)`` as ``mean + L z`` (``L``: the Cholesky factor of ``cov``), then clipped.

    Pyrado name: ``MultivariateNormalDomainParam``.

    Args:
        name: the env field (``"gravity"``).
        mean: the mean, 1-D ``[d]``.
        cov: the covariance ``[d, d]``, symmetric positive definite.
        clip_lo: the lower clipping bound (number or tensor ``[d]``).
        clip_up: the upper clipping bound (likewise).
        roundint: round the clipped draws (kept float64).

    Example:
        >>> import torch
        >>> param = MultivariateNormalDomainParam("gravity", [0.0, 0.0, -9.81], torch.eye(3) * 0.01)
        >>> param.sample(5, torch.Generator().manual_seed(0)).shape
        torch.Size([5, 3])
    """

    distribution_fields = ("mean", "cov", "clip_lo", "clip_up")
    _finite_fields = ("mean", "cov")

    def __init__(
        self,
        name: str,
        mean: object,
        cov: object,
        *,
        clip_lo: object = -math.inf,
        clip_up: object = math.inf,
        roundint: bool = False,
    ) -> None:
        if not isinstance(mean, torch.Tensor):  # refuse a non-vector before the base class takes its shape
            mean = _as_parameter(mean, "mean", None)
        if mean.ndim != 1 or mean.shape[0] == 0:
            raise ValueError(
                f"MultivariateNormalDomainParam({name!r}): mean must be a vector [d] with d >= 1, got shape "
                f"{list(mean.shape)}"
            )
        super().__init__(name, {"mean": mean, "cov": cov}, clip_lo=clip_lo, clip_up=clip_up, roundint=roundint)

    def _param_shape(self, name: str) -> torch.Size:
        return self._value_shape * 2 if name == "cov" else self._value_shape

    def _check_distribution(self, params: Params) -> None:
        cov = params["cov"]
        scale = cov.abs().amax(dim=(-2, -1), keepdim=True)
        _require((cov - cov.mT).abs() <= 1e-9 * scale, "be symmetric", "cov", cov)
        info = torch.linalg.cholesky_ex(cov).info
        _require(info == 0, "be positive definite (its Cholesky factorisation failed)", "cov", cov, whole=True)

    def _unclipped_support(self, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        shape = torch.broadcast_shapes(params["mean"].shape, params["cov"].shape[:-1])
        return _unbounded(shape, params["mean"].device)

    def _draw(self, params: Params, num: int, generator: torch.Generator | None) -> torch.Tensor:
        mean = params["mean"]
        factor = torch.linalg.cholesky(params["cov"])  # [d, d] shared or [num, d, d] per env
        noise = self._noise(torch.randn, num, generator, mean.device)
        return mean + (factor @ noise.unsqueeze(-1)).squeeze(-1)


class BernoulliDomainParam(DomainParam):
    """``val_1`` with probability ``prob_1``, else ``val_0`` (one coin per element), clipped, optionally rounded.

    Pyrado name: ``BernoulliDomainParam``.

    Args:
        name: the env field (``"dof_damping:knee"``).
        val_0: the value of event 0; its shape is the value shape.
        val_1: the value of event 1 (a number or a tensor of the value shape).
        prob_1: the probability of event 1, in ``[0, 1]`` (a number or a tensor of the value shape).
        clip_lo: the lower clipping bound (number or tensor of the value shape).
        clip_up: the upper clipping bound (likewise).
        roundint: round the clipped draws (kept float64).

    Example:
        >>> import torch
        >>> param = BernoulliDomainParam("dof_damping:knee", val_0=0.5, val_1=2.0, prob_1=0.25)
        >>> param
        BernoulliDomainParam('dof_damping:knee', val_0=0.5, val_1=2.0, prob_1=0.25)
        >>> sorted(set(param.sample(100, torch.Generator().manual_seed(0)).tolist()))
        [0.5, 2.0]
    """

    distribution_fields = ("val_0", "val_1", "prob_1", "clip_lo", "clip_up")
    _finite_fields = ("val_0", "val_1", "prob_1")

    def __init__(
        self,
        name: str,
        val_0: object,
        val_1: object,
        prob_1: object,
        *,
        clip_lo: object = -math.inf,
        clip_up: object = math.inf,
        roundint: bool = False,
    ) -> None:
        super().__init__(
            name,
            {"val_0": val_0, "val_1": val_1, "prob_1": prob_1},
            clip_lo=clip_lo,
            clip_up=clip_up,
            roundint=roundint,
        )

    def _check_distribution(self, params: Params) -> None:
        prob = params["prob_1"]
        _require((prob >= 0) & (prob <= 1), "be in [0, 1]", "prob_1", prob)

    def _unclipped_support(self, params: Params) -> tuple[torch.Tensor, torch.Tensor]:
        val_0, val_1 = params["val_0"], params["val_1"]
        return torch.minimum(val_0, val_1), torch.maximum(val_0, val_1)

    def _draw(self, params: Params, num: int, generator: torch.Generator | None) -> torch.Tensor:
        prob = params["prob_1"]
        unit = self._noise(torch.rand, num, generator, prob.device)
        return torch.where(unit < prob, params["val_1"], params["val_0"])


# ------------------------------------------------------------------------------- helpers
def _as_parameter(value: object, name: str, shape: torch.Size | None, source: str | None = None) -> torch.Tensor:
    """``value`` as a float64 tensor: a real number fills ``shape``; anything else must have exactly ``shape``."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a real number or a tensor of real numbers, got the bool {value!r}")
    if shape is not None and isinstance(value, numbers.Real):
        return torch.full(shape, float(value), dtype=FLOAT64)
    tensor = as_constant(value, name)
    if shape is not None and tensor.shape != shape:
        raise ValueError(
            f"{name} must be a number or a tensor of shape {list(shape)} (from {source}'s shape), got shape "
            f"{list(tensor.shape)}"
        )
    return tensor


def _lead(shape: torch.Size, own: torch.Size) -> torch.Size:
    """The leading (per-env) dims of a buffer of ``shape`` whose trailing dims are ``own``."""
    return shape[: len(shape) - len(own)]


def _unbounded(shape: torch.Size, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    return (
        torch.full(shape, -math.inf, dtype=FLOAT64, device=device),
        torch.full(shape, math.inf, dtype=FLOAT64, device=device),
    )


def _first(bad: torch.Tensor) -> tuple[int, ...]:
    """The index of the first True element of ``bad``."""
    return tuple(bad.nonzero()[0].tolist())


def _show(values: torch.Tensor) -> str:
    """A value for messages: whole when small, else its shape."""
    if values.numel() <= _SHOWN:
        return str(values.tolist())
    return f"<{values.dtype} tensor of shape {list(values.shape)}>"


def _require(ok: torch.Tensor, rule: str, name: str, values: torch.Tensor, *, whole: bool = False) -> None:
    """Raise ``ValueError("<name> must <rule>, got ...")`` unless every element of ``ok`` is True.

    ``whole``: ``ok`` holds one flag per matrix of ``values`` (its last two dims), shown whole.
    """
    if bool(ok.all()):
        return
    if values.numel() <= _SHOWN:
        raise ValueError(f"{name} must {rule}, got {values.tolist()}")
    index = _first(~ok)
    if whole:
        raise ValueError(f"{name} must {rule}, got {values[index].tolist()} at index {list(index)}")
    shown = torch.broadcast_to(values, ok.shape)[index].item()
    raise ValueError(f"{name} must {rule}, got {shown} at index {list(index)} (of shape {list(ok.shape)})")
