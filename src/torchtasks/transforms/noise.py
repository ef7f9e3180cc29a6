"""Observation noise per entry and per env: :class:`ObservationNoise`, a TorchRL transform, and :class:`EntryNoise`.

Sensors are noisy and biased. IsaacLab and mjlab corrupt each observation term with a noise model
(``NoiseModelWithAdditiveBias``: a bias drawn per episode plus noise drawn per step); Pyrado's
``GaussianObsNoiseWrapper`` adds Gaussian noise of a per-element mean and std. :class:`ObservationNoise` does both per
named observation entry and per env, and owns the noise's parameters as domain fields
(``"observation_noise:<entry>"``, ``"observation_bias:<entry>"``), so a
:class:`~torchtasks.transforms.DomainRandomization` draws them per env and a
:class:`~torchtasks.transforms.Curriculum` or :class:`~torchtasks.transforms.DifficultyLevels` schedules them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torch import nn
from torchrl.data import Composite, Unbounded

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import check_int, did_you_mean
from torchtasks._memory import td_get, td_set
from torchtasks._torchrl import container_env, key_parts, keys_text, nested_key
from torchtasks.domain import DomainField, check_domain_values, check_field_name, select_fields
from torchtasks.transforms._base import EnvDerivedTransform
from torchtasks.transforms.names import BIAS_KEY, record_entry
from torchtasks.transforms.seeding import GeneratorTransform
from torchtasks.transforms.task import TaskTransform

__all__ = ["BIAS_FIELD", "NOISE_FIELD", "EntryNoise", "ObservationNoise"]

#: the distributions of the noise and of the bias
DISTRIBUTIONS = ("normal", "uniform")
#: the kind of the domain field holding an entry's per-element std of the per-step noise
NOISE_FIELD = "observation_noise"
#: the kind of the domain field holding an entry's per-element std of the per-episode bias
BIAS_FIELD = "observation_bias"
_SQRT3 = math.sqrt(3.0)


class EntryNoise(NamedTuple):
    """The noise of one observation entry: a per-step std, a per-episode bias std, their distributions, where to write.

    ``std`` and ``bias`` are standard deviations in both distributions: ``"normal"`` draws ``N(0, std²)``,
    ``"uniform"`` draws from ``[-√3·std, √3·std)`` (a half-width of ``√3·std``, whose std is ``std``). A number means
    every element of the entry; a tensor gives one value per element and must have the entry's per-env shape exactly.
    ``bias=None`` (the default) means no per-episode bias: no ``observation_bias`` field, no bias entry in the data,
    no draw; give ``bias=0.0`` for a bias that starts at zero and is scheduled or randomized later.

    Example:
        >>> EntryNoise(std=0.01, bias=0.05)
        EntryNoise(std=0.01, bias=0.05, distribution='normal', bias_distribution=None, out_key=None)
    """

    #: the per-element std of the noise drawn at every step (a number: every element; ``>= 0``)
    std: float | torch.Tensor = 0.0
    #: the per-element std of the bias drawn at each reset of an env and held for its episode (``>= 0``; ``None``: no
    #: bias)
    bias: float | torch.Tensor | None = None
    #: the per-step noise's distribution: ``"normal"`` or ``"uniform"``
    distribution: str = "normal"
    #: the bias's distribution (``None``: ``distribution``)
    bias_distribution: str | None = None
    #: where the noisy value goes: ``None`` in place, else a new entry (the clean one stays, e.g. for a critic)
    out_key: NestedKey | None = None


class _Entry(NamedTuple):
    """One noisy entry, checked (:meth:`ObservationNoise._entry`)."""

    #: the observation entry read
    key: NestedKey
    #: where the noisy value is written (``key`` in place)
    out_key: NestedKey
    #: the entry's part of its field names: its key's parts joined by ``":"``
    name: str
    #: the constructor's stds (float64, 0-d for every element, or the entry's per-env shape; ``bias`` ``None``: none)
    std: torch.Tensor
    bias: torch.Tensor | None
    distribution: str
    bias_distribution: str | None
    #: where the episode's bias is written (``None``: no bias)
    bias_key: NestedKey | None


class _Group(NamedTuple):
    """Entries drawn together: one draw ``[*B, width]`` of one distribution and dtype, entry ``k`` reading the next
    ``sizes[k]`` columns (its elements, flattened; viewed as ``shapes[k]``, ``None`` for an entry of one dimension)."""

    distribution: str
    dtype: torch.dtype
    entries: tuple[_Entry, ...]
    sizes: tuple[int, ...]
    shapes: tuple[torch.Size | None, ...]
    width: int


class ObservationNoise(CheckedLoad, GeneratorTransform, EnvDerivedTransform):
    """Add noise drawn at every step and a bias drawn per episode to observation entries, per entry and per env.

    For each entry ``x`` of ``noises`` (``{key: EntryNoise(std, bias, ...)}``) and each env ``i``, the entry written at
    a reset and under ``"next"`` at every step is ``x + b_i + σ_i ⊙ ε`` where ``ε`` is drawn anew at that reset or step
    (standard normal, or uniform on ``[-√3, √3)``: std 1) and ``b_i = β_i ⊙ η`` is drawn at env ``i``'s reset (``η``
    likewise, with the bias's distribution) and held for its episode; ``σ_i`` and ``β_i`` are env ``i``'s per-element
    stds. Every element draws its own ``ε`` and ``η``; an entry without a bias (``EntryNoise(bias=None)``, the
    default) has ``b_i = 0`` and no bias field or entry. With ``EntryNoise(..., out_key=k)`` the noisy value goes to
    ``k`` and the clean entry stays (an asymmetric actor-critic: the actor reads ``k``, the critic the clean one); else
    the entry is replaced. The noisy entries' specs are unbounded (noise can leave an entry's bounds).

    Domain fields (the :class:`~torchtasks.domain.DomainEnv` methods): per entry ``"observation_noise:<entry>"`` (the
    per-element ``σ``) and, for an entry with a bias, ``"observation_bias:<entry>"`` (``β``), of the entry's per-env
    shape, ``>= 0``, nominal the constructor's values (a nested key's parts are joined by ``":"``:
    ``("agent", "joint_pos")`` gives ``"observation_noise:agent:joint_pos"``). A
    :class:`~torchtasks.transforms.DomainRandomization` after this transform draws them per env; a new ``σ`` applies
    from the next reset or step, a new ``β`` from the env's next reset. A ``Curriculum`` or ``DifficultyLevels`` sets
    their distributions (``"domain.observation_noise:joint_pos.mean"``).

    An entry's episode bias is written to the entry ``"<entry_key>_<entry>"`` (``"observation_bias_joint_pos"``; a
    nested entry's parts joined by ``":"``) at reset and every step, so offline users see what each episode had. An
    entry a :class:`~torchtasks.transforms.TaskTransform` of the env reads as its state (or goal) is refused in place:
    the task keeps judging the true state. On an env that steps from the data's ``"observation"``
    (:class:`~torchtasks.envs.PendulumEnv`), write a copy (``out_key``).

    Randomness: one generator (``seed=k``; ``None``: torch's global one until ``env.set_seed(s)``) draws, per step,
    one ``[*B, n]`` per distribution and dtype for its entries' ``ε``, and per reset first the ``η`` of every env.
    Run state (``state_dict``): the generator, every env's ``σ``, ``β`` and bias; a checkpoint of other entries,
    distributions or shapes is refused and changes nothing.

    Args:
        noises: the noise of each observation entry, by key (a string or a tuple of strings).
        entry_key: the prefix of the bias entries (``"<entry_key>_<entry>"``; a nested key's last part is the prefix,
            its first parts the node the entries go to).
        seed: seed of the transform's own generator (``None``: torch's global one until ``env.set_seed``).

    Example:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.transforms import EntryNoise, ObservationNoise
        >>> noise = ObservationNoise({"observation": EntryNoise(std=0.01, bias=0.1, out_key="noisy")}, seed=0)
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), noise)
        >>> data = env.rollout(3)
        >>> offset = data["next", "noisy"] - data["next", "observation"]  # the bias plus the step's noise
        >>> bias = data["next", "observation_bias_observation"]
        >>> bool(((offset - bias).abs() < 0.1).all()), bool((bias[:, 0] == bias[:, 2]).all())  # held per episode
        (True, True)
        >>> [field.name for field in noise.domain_fields()]
        ['observation_noise:observation', 'observation_bias:observation']
    """

    def __init__(
        self,
        noises: Mapping[NestedKey, EntryNoise],
        *,
        entry_key: NestedKey = BIAS_KEY,
        seed: int | None = None,
    ) -> None:
        if not isinstance(noises, Mapping) or not noises:
            raise TypeError(
                "ObservationNoise: noises must be a non-empty mapping of observation keys to EntryNoise, got "
                f"{noises!r}"
            )
        self.entry_key = nested_key(entry_key, "ObservationNoise: entry_key")
        entries = [self._entry(key, noise) for key, noise in noises.items()]
        _check_distinct(entries)
        super().__init__(
            in_keys=[entry.key for entry in entries],
            out_keys=[entry.out_key for entry in entries] + [e.bias_key for e in entries if e.bias_key is not None],
        )
        self.entries = tuple(entries)
        #: the entries with a per-episode bias
        self.biased = tuple(entry for entry in entries if entry.bias is not None)
        #: every env's per-element std of the per-step noise (every entry), of the per-episode bias and the episode's
        #: bias (the entries with a bias), by entry name (float64 ``[*B, *entry shape]``, made with the specs)
        self.noise_std = nn.Module()
        self.bias_std = nn.Module()
        self.bias = nn.Module()
        for entry in entries:
            self.noise_std.register_buffer(entry.name, torch.empty(0, dtype=torch.float64))
        for entry in self.biased:
            for module in (self.bias_std, self.bias):
                module.register_buffer(entry.name, torch.empty(0, dtype=torch.float64))
        self.generator = None if seed is None else torch.Generator().manual_seed(check_int(seed, "seed"))

    def _entry(self, key: object, noise: object) -> _Entry:
        key = nested_key(key, "ObservationNoise: a key of noises")
        if not isinstance(noise, EntryNoise):
            raise TypeError(
                f"ObservationNoise: noises[{key!r}] must be an EntryNoise(std=..., bias=...), got {noise!r}"
            )
        name = ":".join(key_parts(key))
        try:
            check_field_name(name)
        except ValueError:
            raise ValueError(
                f"ObservationNoise: the entry {key!r} names domain fields '{NOISE_FIELD}:{name}', which must hold "
                "neither '.' nor '/'; rename the entry (e.g. with torchrl's RenameTransform)"
            ) from None
        std = _std(noise.std, f"ObservationNoise: the std of {key!r}")
        distribution = _distribution(noise.distribution, f"ObservationNoise: the distribution of {key!r}")
        bias = bias_distribution = bias_key = None
        if noise.bias is not None:
            bias = _std(noise.bias, f"ObservationNoise: the bias of {key!r}")
            bias_distribution = distribution
            bias_key = unravel_key(record_entry(key_parts(self.entry_key), name))
        if noise.bias_distribution is not None:
            checked = _distribution(noise.bias_distribution, f"ObservationNoise: the bias_distribution of {key!r}")
            if bias is None:
                raise ValueError(
                    f"ObservationNoise: the bias_distribution of {key!r} is {checked!r} but it has no bias "
                    "(bias=None); give EntryNoise(bias=...) a std, or leave bias_distribution out"
                )
            bias_distribution = checked
        out_key = (
            key if noise.out_key is None else nested_key(noise.out_key, f"ObservationNoise: the out_key of {key!r}")
        )
        return _Entry(key, out_key, name, std, bias, distribution, bias_distribution, bias_key)

    # ------------------------------------------------------------------ seeding
    def set_seed(self, seed: int) -> None:
        """Seed the transform's own generator with ``seed``: the draws from then on (the running episodes keep their
        biases). ``env.set_seed(s)`` calls it with a seed derived from ``s`` (:mod:`torchtasks.transforms.seeding`)."""
        self.generator = torch.Generator().manual_seed(check_int(seed, "ObservationNoise.set_seed: seed"))

    def seed_identity(self) -> str:
        """``"ObservationNoise(<entry names>)"``: mixed into the seed ``env.set_seed`` derives for it."""
        return f"{type(self).__name__}({[entry.name for entry in self.entries]!r})"

    # ------------------------------------------------------------------ set-up
    def _forget_setup(self) -> None:
        self.__dict__.pop("_cast", None)
        self.__dict__.pop("_bias_cast", None)

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_cast", None)
        state.pop("_bias_cast", None)
        return state

    def _check_placement(self) -> None:
        """Refuse noise in place on an entry a TaskTransform of the env reads as its state or goal."""
        home = self.home_transforms()
        if home is None:
            return
        in_place = {entry.key for entry in self.entries if entry.out_key == entry.key}
        for task in (t for t in home[0] if isinstance(t, TaskTransform)):
            read = [(key, "state") for key in task.state_keys] + [(task.goal_key, "goal")]
            for key, what in read:
                if key in in_place:
                    raise ValueError(
                        f"ObservationNoise: the TaskTransform of {type(task.task).__name__} reads {key!r} as its "
                        f"{what}, and noise in place there would make the task judge noisy values: the task keeps "
                        f"judging the true {what}. Give the task its own {what} entry (an entry the noise leaves "
                        f"alone), or write the noisy value elsewhere: EntryNoise(..., out_key='noisy_...')"
                    )

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._check_placement()
        batch, device = observation_spec.shape, observation_spec.device
        keys = list(observation_spec.keys(True, True))
        shapes, dtypes = {}, {}
        for entry in self.entries:
            if entry.key not in keys:
                raise ValueError(
                    f"ObservationNoise: no observation entry {entry.key!r} in the env"
                    f"{did_you_mean(str(entry.key), [str(k) for k in keys], n=3)}; the entries are {keys_text(keys)}"
                )
            spec = observation_spec[entry.key]
            if not spec.dtype.is_floating_point:
                raise TypeError(
                    f"ObservationNoise: the entry {entry.key!r} has dtype {spec.dtype}; noise is added to floating "
                    "entries only"
                )
            shape = spec.shape[len(batch) :]
            for what, value in (("std", entry.std), ("bias", entry.bias)):
                if value is not None and value.dim() and value.shape != shape:
                    raise ValueError(
                        f"ObservationNoise: the {what} of {entry.key!r} must be a number (every element) or a tensor "
                        f"of the entry's per-env shape {list(shape)}, got shape {list(value.shape)}"
                    )
            if entry.out_key != entry.key and entry.out_key in keys:
                raise ValueError(
                    f"ObservationNoise: the out_key {entry.out_key!r} of {entry.key!r} already names an entry of the "
                    "env; write the noisy copy to a new key"
                )
            shapes[entry.name], dtypes[entry.name] = shape, spec.dtype
            noisy = Unbounded(shape=spec.shape, dtype=spec.dtype, device=spec.device)
            observation_spec[entry.out_key] = noisy
            if entry.bias_key is not None:
                if entry.bias_key in keys:
                    raise ValueError(
                        f"ObservationNoise: the bias entry {entry.bias_key!r} of {entry.key!r} already names an entry "
                        "of the env; give the ObservationNoise another entry_key"
                    )
                observation_spec[entry.bias_key] = noisy.clone()
        self.__dict__["_shapes"], self.__dict__["_dtypes"] = shapes, dtypes
        self.__dict__["_device"] = None if device is None else torch.device(device)
        self.__dict__["_noise_groups"] = _groups(self.entries, shapes, lambda e: (e.distribution, dtypes[e.name]))
        self.__dict__["_bias_groups"] = _groups(self.biased, shapes, lambda e: (e.bias_distribution, torch.float64))
        self.__dict__.pop("_fields", None)
        self._make_state(batch, device)
        return observation_spec

    def _make_state(self, batch: torch.Size, device: torch.device | None) -> None:
        """Give the per-env buffers the env's batch (the constructor's stds, zero biases) unless they have it; held
        values of another batch (loaded) are refused."""
        shapes = self.__dict__["_shapes"]
        for entry in self.entries:
            shape = batch + shapes[entry.name]
            initial = [(self.noise_std, entry.std)]
            if entry.bias is not None:
                initial += [(self.bias_std, entry.bias), (self.bias, torch.zeros(()))]
            for module, value in initial:
                held = module._buffers[entry.name]
                if held.shape == shape:
                    continue
                if held.numel():
                    raise ValueError(
                        f"ObservationNoise: it holds the values of {entry.key!r} for a batch and entry shape "
                        f"{list(held.shape)}, but the env gives {list(shape)}: load a checkpoint of this env"
                    )
                module._buffers[entry.name] = value.to(device=device, dtype=torch.float64).expand(shape).clone()
        self.__dict__["_batch"] = batch
        self._forget_setup()

    def _entry_shapes(self) -> dict[str, torch.Size]:
        """The entries' per-env shapes, from the env's specs (built now if they are not yet)."""
        shapes = self.__dict__.get("_shapes")
        if shapes is None:
            env = container_env(self)
            if env is not None:
                env.observation_spec  # noqa: B018  (builds the specs: transform_observation_spec learns the shapes)
            shapes = self.__dict__.get("_shapes")
        if shapes is None:
            raise ValueError(
                "ObservationNoise: its domain fields have the shapes of its entries, which come from the env's "
                "observation spec: put it in an env first"
            )
        return shapes

    # ------------------------------------------------------------------ domain fields (the DomainEnv methods)
    def _table(self) -> dict[str, DomainField]:
        """Every field by name: per entry its noise std, then its bias std (the nominal values: the constructor's);
        cached until the specs are built again."""
        table = self.__dict__.get("_fields")
        if table is not None:
            return table
        shapes = self._entry_shapes()
        table = {}
        for entry in self.entries:
            shape = shapes[entry.name]
            for kind, what, nominal in ((NOISE_FIELD, "per-step noise", entry.std), (BIAS_FIELD, "bias", entry.bias)):
                if nominal is None:  # no bias
                    continue
                name = f"{kind}:{entry.name}"
                description = f"the per-element std of the {what} of {entry.key!r}"
                field = DomainField(
                    name, shape, nominal.expand(shape).clone(), 0.0, math.inf, False, (), False, description
                )
                table[name] = field
        self.__dict__["_fields"] = table
        return table

    def domain_fields(self, names: Sequence[str] | None = None) -> list[DomainField]:
        """The domain fields ``names`` names (``None``: all: per entry ``"observation_noise:<entry>"`` then, with a
        bias, ``"observation_bias:<entry>"``), see :class:`~torchtasks.domain.DomainEnv`."""
        return select_fields(self._table(), names, type(self).__name__)

    def absent_field_reason(self, name: object) -> str | None:
        """Why ``name`` is not a domain field although it names one of the entries, or ``None``: an entry without a
        bias has no ``"observation_bias:<entry>"``.

        Example:
            >>> noise = ObservationNoise({"observation": EntryNoise(std=0.1)})
            >>> noise.absent_field_reason("observation_bias:observation")[:56]
            "'observation_bias:observation' is not a field: the entry"
        """
        for entry in self.entries:
            if entry.bias is None and name == f"{BIAS_FIELD}:{entry.name}":
                return (
                    f"{name!r} is not a field: the entry {entry.key!r} has no per-episode bias (EntryNoise(bias=None), "
                    "the default); give it EntryNoise(bias=0.0) to draw or schedule its bias std"
                )
        return None

    def _field_buffer(self, name: str) -> tuple[nn.Module, str]:
        kind, entry = name.split(":", 1)
        return (self.noise_std if kind == NOISE_FIELD else self.bias_std), entry

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give the envs of ``mask`` (bool ``[*B]``; ``None``: all) the stds ``values[name]`` (float64
        ``[*B, *entry shape]``, ``>= 0``); the others keep theirs. A noise std applies from the next reset or step, a
        bias std from the next bias drawn (the env's next reset)."""
        batch = self.__dict__.get("_batch")
        if batch is None:
            self._entry_shapes()
            batch = self.__dict__["_batch"]
        mask = check_domain_values(self._table(), values, mask, batch, type(self).__name__)
        for name, value in values.items():
            module, entry = self._field_buffer(name)
            held = module._buffers[entry]
            rows = mask.to(held.device).reshape(batch + (1,) * (held.dim() - len(batch)))
            module._buffers[entry] = torch.where(rows, value.to(held.device), held)
        self.__dict__.pop("_cast", None)

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's current std of each field named (float64 ``[*B, *entry shape]``)."""
        self._entry_shapes()
        values = {}
        for field in self.domain_fields(names):
            module, entry = self._field_buffer(field.name)
            values[field.name] = module._buffers[entry].clone()
        return values

    # ------------------------------------------------------------------ drawing
    def _standard(self, group: _Group, batch: torch.Size) -> torch.Tensor:
        """The group's draws ``[*B, width]`` of mean 0 and std 1 (normal, or uniform on ``[-√3, √3)``), drawn on the
        CPU by the own generator and moved, once, to the device of the env's specs (where the stds and biases are)."""
        shape = (*batch, group.width)
        if group.distribution == "normal":
            draw = torch.randn(shape, generator=self.generator, dtype=group.dtype)
        else:  # -√3 + 2√3 u: the arithmetic of rand(...) * 2√3 - √3, in one op fewer
            draw = torch.empty(shape, dtype=group.dtype).uniform_(-_SQRT3, _SQRT3, generator=self.generator)
        device = self.__dict__["_device"]
        return draw if device is None or device.type == "cpu" else draw.to(device)

    def _casts(self, name: str) -> dict[str, torch.Tensor]:
        """Each entry's noise std (``"_cast"``) or bias (``"_bias_cast"``) in the entry's dtype and device, cached until
        it changes (a draw of the randomization, a reset, a load)."""
        cast = self.__dict__.get(name)
        if cast is None:
            dtypes = self.__dict__["_dtypes"]
            module, entries = (self.noise_std, self.entries) if name == "_cast" else (self.bias, self.biased)
            # a copy even in the buffer's dtype: a load writes into the buffers in place; a cast is replaced, never
            # written into
            cast = {entry.name: module._buffers[entry.name].to(dtypes[entry.name], copy=True) for entry in entries}
            self.__dict__[name] = cast
        return cast

    def _write(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write each entry's noisy value (the bias plus a fresh draw times the std) and the episode's bias: one draw
        per group of entries (a distribution and dtype), each entry reading its columns."""
        stds, biases = self._casts("_cast"), self._casts("_bias_cast")
        batch = tensordict.batch_size
        for group in self.__dict__["_noise_groups"]:
            units = torch.split_with_sizes(self._standard(group, batch), group.sizes, -1)
            for entry, unit, shape in zip(group.entries, units, group.shapes, strict=True):
                value = td_get(tensordict, entry.key)
                if value is None:
                    raise KeyError(
                        f"ObservationNoise: the entry {entry.key!r} is missing from the data; the entries are "
                        f"{keys_text(tensordict.keys(True, True))}"
                    )
                unit = unit if shape is None else unit.unflatten(-1, shape)
                bias = biases.get(entry.name)
                if bias is None:
                    td_set(tensordict, entry.out_key, torch.addcmul(value, stds[entry.name], unit))
                else:
                    td_set(tensordict, entry.out_key, torch.addcmul(value + bias, stds[entry.name], unit))
                    # a copy of this episode's bias: no entry of a step shares storage with another's
                    td_set(tensordict, entry.bias_key, bias.clone())
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        """Draw a new bias for the envs that reset (every env draws: the generator's use does not depend on which
        reset), then write the reset's noisy entries."""
        batch = tensordict_reset.batch_size
        if self.__dict__.get("_batch") != batch:
            self._entry_shapes()
            if self.__dict__.get("_batch") != batch:
                self._make_state(batch, tensordict_reset.device)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        dtypes, biases = self.__dict__["_dtypes"], {}
        rows_of: dict[int, torch.Tensor] = {}  # the reset mask shaped for an entry of each number of dims
        for group in self.__dict__["_bias_groups"]:
            units = torch.split_with_sizes(self._standard(group, batch), group.sizes, -1)
            for entry, unit, shape in zip(group.entries, units, group.shapes, strict=True):
                held = self.bias._buffers[entry.name]
                unit = unit if shape is None else unit.unflatten(-1, shape)
                new = self.bias_std._buffers[entry.name] * unit
                if reset is not None:
                    rows = rows_of.get(held.dim())
                    if rows is None:
                        rows = reset.reshape(batch + (1,) * (held.dim() - len(batch)))
                        rows = rows_of[held.dim()] = rows if rows.device == held.device else rows.to(held.device)
                    new = torch.where(rows, new, held)
                self.bias._buffers[entry.name] = new
                biases[entry.name] = new.to(dtypes[entry.name], copy=True)
        self.__dict__["_bias_cast"] = biases
        return self._write(tensordict_reset)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._write(next_tensordict)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Leave stored data as it is: its noisy entries and biases are in it."""
        return tensordict

    # ------------------------------------------------------------------ checkpoints
    def _saved_configuration(self) -> dict[str, Any]:
        """The configuration a checkpoint must match: the entries and their distributions."""
        return {"entries": {entry.name: [entry.distribution, entry.bias_distribution] for entry in self.entries}}

    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        """Refuse the checkpoint of another noise: other entries or distributions, a generator state of another kind."""
        saved = state_dict.get(prefix + "_extra_state")
        own = self.get_extra_state()
        if not isinstance(saved, Mapping) or "entries" not in saved:
            raise ValueError(
                "ObservationNoise.load_state_dict: the checkpoint has no ObservationNoise configuration (_extra_state "
                f"with 'entries'), got {saved!r}"
            )
        if saved["entries"] != own["entries"]:
            raise ValueError(
                f"ObservationNoise.load_state_dict: the checkpoint is of another noise (entries and distributions: "
                f"saved {saved['entries']!r}, here {own['entries']!r}); build the ObservationNoise as saved"
            )
        for head, entries in (("noise_std.", self.entries), ("bias_std.", self.biased), ("bias.", self.biased)):
            for entry in entries:
                value = state_dict.get(prefix + head + entry.name)
                if isinstance(value, torch.Tensor) and value.dtype != torch.float64:
                    raise ValueError(
                        f"ObservationNoise.load_state_dict: the saved {head[:-1]} of {entry.key!r} must be float64, "
                        f"got {value.dtype}"
                    )
        self._check_saved_generator(saved)

    def _prepare_load(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        # the per-env buffers take the saved shapes (a transform not yet in an env has empty ones); dtypes are checked
        for module, head in ((self.noise_std, "noise_std."), (self.bias_std, "bias_std."), (self.bias, "bias.")):
            for name in list(module._buffers):
                saved = state_dict.get(prefix + head + name)
                own = module._buffers[name]
                if isinstance(saved, torch.Tensor) and saved.shape != own.shape:
                    module._buffers[name] = torch.empty(saved.shape, dtype=own.dtype, device=own.device)

    def _check_loaded(self) -> None:
        """Refuse loaded values of another batch or entry shape, and stds below 0 or not finite."""
        self._forget_setup()
        shapes = self.__dict__.get("_shapes")
        batch = self.__dict__.get("_batch")
        for entry in self.entries:
            held = {
                what: module._buffers[entry.name]
                for what, module in (("noise_std", self.noise_std), ("bias_std", self.bias_std), ("bias", self.bias))
                if entry.name in module._buffers
            }
            if len({tuple(value.shape) for value in held.values()}) > 1:
                raise ValueError(
                    f"ObservationNoise.load_state_dict: the saved values of {entry.key!r} must share one shape, got "
                    + ", ".join(f"{what} {list(value.shape)}" for what, value in held.items())
                )
            shape = held["noise_std"].shape
            if shapes is not None and batch is not None and shape != batch + shapes[entry.name]:
                raise ValueError(
                    f"ObservationNoise.load_state_dict: the checkpoint holds values of {entry.key!r} of shape "
                    f"{list(shape)} ([*batch, *entry shape]), but this env gives {list(batch + shapes[entry.name])}: "
                    "load a checkpoint of this env"
                )
            for what in [what for what in ("noise_std", "bias_std") if what in held]:
                value = held[what]
                if not bool((torch.isfinite(value) & (value >= 0)).all()):
                    raise ValueError(
                        f"ObservationNoise.load_state_dict: the saved {what} of {entry.key!r} must be finite and >= 0, "
                        f"got {value.tolist()}"
                    )
            if "bias" in held and not bool(torch.isfinite(held["bias"]).all()):
                raise ValueError(f"ObservationNoise.load_state_dict: the saved bias of {entry.key!r} must be finite")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({{{', '.join(_entry_text(entry) for entry in self.entries)}}})"


def _groups(entries: Sequence[_Entry], shapes: Mapping[str, torch.Size], group_of: Any) -> tuple[_Group, ...]:
    """The entries drawn together: by ``group_of(entry)`` (a distribution and dtype) in the order of first appearance,
    each group's columns the entries' flattened elements in the order given."""
    members: dict[tuple[str, torch.dtype], list[_Entry]] = {}
    for entry in entries:
        members.setdefault(group_of(entry), []).append(entry)
    groups = []
    for (distribution, dtype), group in members.items():
        sizes = tuple(math.prod(shapes[entry.name]) for entry in group)
        viewed = tuple(None if len(shapes[entry.name]) == 1 else shapes[entry.name] for entry in group)
        groups.append(_Group(distribution, dtype, tuple(group), sizes, viewed, sum(sizes)))
    return tuple(groups)


def _entry_text(entry: _Entry) -> str:
    text = f"{entry.key!r}: std={_shown(entry.std)}"
    if entry.bias is not None:
        text += f", bias={_shown(entry.bias)}"
    text += f", {entry.distribution}"
    if entry.bias is not None and entry.bias_distribution != entry.distribution:
        text += f"/{entry.bias_distribution}"
    return text + (f" -> {entry.out_key!r}" if entry.out_key != entry.key else "")


def _shown(value: torch.Tensor) -> object:
    return value.item() if value.dim() == 0 else value.tolist()


def _std(value: object, name: str) -> torch.Tensor:
    """A std as a float64 tensor (0-d for a number), refused unless real, finite and ``>= 0``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, torch.Tensor)):
        raise TypeError(f"{name} must be a number or a float tensor (a std), got {value!r}")
    if isinstance(value, torch.Tensor) and not value.is_floating_point():
        raise TypeError(f"{name} must be a float tensor, got dtype {value.dtype}")
    tensor = torch.as_tensor(value, dtype=torch.float64).detach().cpu().clone()
    if not bool(torch.isfinite(tensor).all()) or bool((tensor < 0).any()):
        raise ValueError(f"{name} is a standard deviation and must be finite and >= 0, got {tensor.tolist()}")
    return tensor


def _distribution(value: object, name: str) -> str:
    if value not in DISTRIBUTIONS:
        raise ValueError(f"{name} must be one of {list(DISTRIBUTIONS)}, got {value!r}")
    return value


def _check_distinct(entries: Sequence[_Entry]) -> None:
    """Refuse two entries of one field name, and an out_key that is another entry or another's out_key."""
    names: dict[str, NestedKey] = {}
    for entry in entries:
        other = names.setdefault(entry.name, entry.key)
        if other != entry.key:
            raise ValueError(
                f"ObservationNoise: the entries {other!r} and {entry.key!r} both name the fields "
                f"'{NOISE_FIELD}:{entry.name}'; noise one of them, or rename one"
            )
    keys = [entry.key for entry in entries]
    if len(set(keys)) < len(keys):
        raise ValueError(f"ObservationNoise: an entry is given twice in {keys}")
    written = [entry.out_key for entry in entries]
    for entry in entries:
        if entry.out_key != entry.key and (entry.out_key in keys or written.count(entry.out_key) > 1):
            raise ValueError(
                f"ObservationNoise: the out_key {entry.out_key!r} of {entry.key!r} is another noisy entry or another's "
                "out_key; give each noisy copy its own key"
            )
    for entry in entries:
        if entry.bias_key is not None and entry.bias_key in written:
            raise ValueError(
                f"ObservationNoise: the bias entry {entry.bias_key!r} of {entry.key!r} is an out_key; give the noisy "
                "copy another key"
            )
