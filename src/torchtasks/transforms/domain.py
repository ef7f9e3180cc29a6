"""Domain randomization: per-env physics drawn from domain distributions, as a TorchRL transform.

:class:`DomainRandomization` draws a value of each of its :class:`~torchtasks.domain.DomainParam`\\ s for
every env and gives it to the base env (a :class:`~torchtasks.domain.DomainEnv`: a
:class:`~torchtasks.envs.BatchedMujocoEnv`, a :class:`~torchtasks.envs.PendulumEnv`), once per env
(``when="startup"``), at each env's own reset (``"reset"``, Pyrado's ``DomainRandWrapperLive``) or every
``every`` steps (``"interval"``); with ``cycle`` the values come from a stored set of domains, in turn
(Pyrado's ``DomainRandWrapperBuffer``). The drawn values are entries of the data, and run state.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Composite, Unbounded

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import check_int, check_positive_int
from torchtasks._memory import set_records
from torchtasks._torchrl import container_env, key_parts, nested_key
from torchtasks.domain import DomainEnv, DomainField, DomainParam
from torchtasks.transforms._base import EnvDerivedTransform
from torchtasks.transforms.domain_owners import domain_owners
from torchtasks.transforms.names import DOMAIN_KEY
from torchtasks.transforms.seeding import GeneratorTransform

__all__ = ["DomainRandomization"]

#: the moments a DomainRandomization draws
WHEN = ("startup", "reset", "interval")


class _Draw(NamedTuple):
    """A draw before the env took it (:meth:`DomainRandomization._draw`)."""

    #: every env's values by field (the new ones where the envs needed values)
    values: dict[str, torch.Tensor]
    #: the stored domains by field drawn by this draw (a cycle's first); ``None``: none drawn
    domains: dict[str, torch.Tensor] | None
    #: with a cycle, the index of the next stored domain after this draw (a 0-d int64 tensor); ``None`` without
    next_domain: torch.Tensor | None


class DomainRandomization(CheckedLoad, GeneratorTransform, EnvDerivedTransform):
    """Draw per-env physics from domain distributions and give them to the base env, at startup, resets or intervals.

    Each :class:`~torchtasks.domain.DomainParam` names a domain field of the base env
    (``env.base_env.domain_fields()`` lists them: ``"body_mass:torso"``, ``"gravity"``, ...) or of a transform
    before it in the env that owns fields (an :class:`~torchtasks.transforms.ObservationNoise`'s
    ``"observation_noise:<entry>"``; :mod:`~torchtasks.transforms.domain_owners` routes each name to its owner). The
    transform draws one value per env and param and gives it to the owner
    (:meth:`~torchtasks.domain.DomainEnv.set_domain`):
    ``when="reset"`` at every reset of an env, before the base env resets; ``"startup"`` once per env, at its
    first reset; ``"interval"`` at its first reset and then before the step after every ``every`` steps of that
    env (across episodes). ``cycle=K`` draws ``K`` domains at the first draw and gives each env that needs values
    the next one of that stored set, in turn (Pyrado's ``DomainRandWrapperBuffer``); ``cycle={name: values}``
    gives the set, and ``shard=(k, n)`` keeps its rows ``k, k + n, ...``: ``n`` workers together take every
    domain once per pass. Without ``cycle`` every draw is fresh (Pyrado's ``DomainRandWrapperLive``).

    Entries: every env's current values, float64 ``[*B, *value_shape]`` (``[*B, 1]`` for a scalar field, as
    TorchRL's ``"reward"``: a privileged critic concatenates them with the observation) under ``(entry_key, name)``,
    at reset and at every step; under ``"next"`` the values the step ran with.

    Run state (``state_dict``): the drawn values, the interval counters, the stored domains and the generator;
    a checkpoint of other params, ``when``, ``every``, ``cycle`` or ``shard`` is refused. ``env.set_seed(s)``
    seeds the generator per worker (:meth:`set_seed`). Distribution parameters are targets
    ``"domain.<field>.<parameter>"`` of a :class:`~torchtasks.transforms.Curriculum` or
    :class:`~torchtasks.transforms.DifficultyLevels` placed after this transform, when it draws again and again
    (:meth:`unwritable_reason`). See ``docs/domain_randomization.md``.

    Args:
        params: the domain parameters, one per field.
        when: ``"reset"``, ``"startup"`` or ``"interval"``.
        every: the steps between draws of ``when="interval"`` (required there, refused otherwise).
        cycle: ``None`` (fresh draws), the number of stored domains to draw, or the stored domains
            (float64 ``[K, *value_shape]`` per field).
        shard: ``(index, count)``: keep the given stored domains ``index, index + count, ...`` (one shard per
            worker of ``count``); needs ``cycle={...}`` with at least ``count`` domains.
        entry_key: where the drawn values are written (a nested key; one entry per param).
        seed: seed of the transform's own generator (``None``: torch's global one until ``env.set_seed``).

    Example:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchtasks.domain import UniformDomainParam
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.transforms import DomainRandomization
        >>> randomization = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.5)], seed=0)
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), randomization)
        >>> masses = env.reset()["domain", "mass"]
        >>> masses.shape, bool(((masses >= 0.5) & (masses <= 1.5)).all())
        (torch.Size([4, 1]), True)
        >>> torch.equal(env.base_env.domain_values(["mass"])["mass"], masses[:, 0])
        True
    """

    def __init__(
        self,
        params: Sequence[DomainParam],
        *,
        when: str = "reset",
        every: int | None = None,
        cycle: int | Mapping[str, torch.Tensor] | None = None,
        shard: tuple[int, int] | None = None,
        entry_key: str | tuple[str, ...] = DOMAIN_KEY,
        seed: int | None = None,
    ) -> None:
        if isinstance(params, DomainParam) or not isinstance(params, Sequence) or not params:
            raise TypeError(f"DomainRandomization: params must be a non-empty sequence of DomainParams, got {params!r}")
        for i, param in enumerate(params):
            if not isinstance(param, DomainParam):
                raise TypeError(f"DomainRandomization: params[{i}] must be a DomainParam, got {type(param).__name__}")
        names = [param.name for param in params]
        if len(set(names)) < len(names):
            raise ValueError(f"DomainRandomization: params must name distinct domain fields, got {names}")
        if when not in WHEN:
            raise ValueError(f"DomainRandomization: when must be one of {list(WHEN)}, got {when!r}")
        if (when == "interval") != (every is not None):
            raise ValueError(
                "DomainRandomization: every (the steps between draws) is required with when='interval' and refused "
                f"otherwise, got when={when!r}, every={every!r}"
            )
        self.entry_key = nested_key(entry_key, "DomainRandomization: entry_key")
        keys = [(*key_parts(self.entry_key), name) for name in names]
        super().__init__(in_keys=[], out_keys=keys)
        self.when = when
        self.every = None if every is None else check_positive_int(every, "DomainRandomization: every")
        self.names = tuple(names)
        self.__dict__["_keys"] = keys
        #: the domain parameters by field name
        self.params = nn.ModuleDict({param.name: param for param in params})
        #: every env's current values, one buffer per field (``[*B, *value_shape]``, made with the specs)
        self.drawn = nn.Module()
        for param in params:
            self.drawn.register_buffer(param.name, torch.empty(0, dtype=torch.float64))
        #: whether each env has had its first draw, and its steps since its last draw (when="interval")
        self.register_buffer("started", torch.empty(0, dtype=torch.bool))
        self.register_buffer("steps", torch.empty(0, dtype=torch.int64))
        #: ``(index, count)``: the given stored domains this transform takes (``None``: all of them)
        self.shard = _check_shard(shard, cycle)
        self.cycle_size = self._register_cycle(cycle, params)
        #: whether the stored domains were given (``cycle={...}``) rather than drawn (``cycle=K``)
        self._given_domains = isinstance(cycle, Mapping)
        self.generator = None if seed is None else torch.Generator().manual_seed(check_int(seed, "seed"))

    def _register_cycle(self, cycle: object, params: Sequence[DomainParam]) -> int | None:
        """Register the stored domains (``domains.<name>``), whether they are drawn yet, and the next one's index."""
        self.domains = nn.Module()
        self.register_buffer("next_domain", torch.zeros((), dtype=torch.int64))
        self.register_buffer("domains_drawn", torch.tensor(False))
        if cycle is None:
            return None
        if isinstance(cycle, Mapping):
            if set(cycle) != set(self.names):
                raise ValueError(
                    "DomainRandomization: cycle must give stored values for exactly the params' fields "
                    f"{list(self.names)}, got {sorted(map(str, cycle))}"
                )
            sizes = set()
            for param in params:
                values = cycle[param.name]
                expected = f"a float64 tensor [K, {', '.join(map(str, param.value_shape))}]".replace(", ]", "]")
                if not isinstance(values, torch.Tensor) or values.dtype != torch.float64:
                    raise TypeError(
                        f"DomainRandomization: cycle[{param.name!r}] must be {expected}, got "
                        + (f"{values.dtype} {list(values.shape)}" if isinstance(values, torch.Tensor) else repr(values))
                    )
                if values.dim() < 1 or values.shape[1:] != param.value_shape or values.shape[0] == 0:
                    raise ValueError(
                        f"DomainRandomization: cycle[{param.name!r}] must have shape [K, *{list(param.value_shape)}] "
                        f"with K >= 1 (one row per stored domain), got {list(values.shape)}"
                    )
                sizes.add(values.shape[0])
            if len(sizes) > 1:
                raise ValueError(
                    "DomainRandomization: cycle's values must hold the same number of domains (rows), got "
                    f"{sorted(sizes)}"
                )
            size = sizes.pop()
            index, count = (0, 1) if self.shard is None else self.shard
            if count > size:
                raise ValueError(
                    f"DomainRandomization: shard={self.shard} splits the {size} given domains into {count} shards, "
                    f"so some shards would hold none; use at most {size} shards (workers)"
                )
            for param in params:
                self.domains.register_buffer(param.name, cycle[param.name].detach()[index::count].clone())
            self.domains_drawn.fill_(True)
            return self.domains._buffers[self.names[0]].shape[0]
        size = check_positive_int(cycle, "DomainRandomization: cycle (the number of stored domains)")
        for param in params:
            self.domains.register_buffer(param.name, torch.zeros(size, *param.value_shape, dtype=torch.float64))
        return size

    # ------------------------------------------------------------------ seeding
    def set_seed(self, seed: int) -> None:
        """Seed the transform's own generator with ``seed`` and start the run's draws again from it.

        ``env.set_seed(s)`` calls it with a seed derived from ``s`` (:mod:`torchtasks.transforms.seeding`). Every
        env's next reset is its first draw under the new seed (``when="startup"`` and ``"interval"`` too: the envs
        count as not started, the interval counters start again); a stored set drawn with ``cycle=K`` is drawn
        again at that draw, a given set starts again from its first domain. The running episodes keep the physics
        they were reset with, so the data's entries always equal the physics the env runs. A run therefore repeats
        from its first frame when it is seeded before its first reset (``env.set_seed(s)``, then build the
        ``Collector``) or reset after the seed (``collector.set_seed(s); collector.reset()``, as TorchRL's
        multi-process collectors do).

        Example:
            >>> import torch
            >>> from torchrl.envs import TransformedEnv
            >>> from torchtasks.domain import UniformDomainParam
            >>> from torchtasks.envs import PendulumEnv
            >>> from torchtasks.transforms import DomainRandomization
            >>> env = TransformedEnv(
            ...     PendulumEnv(batch_size=[3]), DomainRandomization([UniformDomainParam("mass", 1.0, 0.5)]))
            >>> running = env.reset()["domain", "mass"]
            >>> _ = env.set_seed(5)
            >>> torch.equal(env.base_env.domain_values(["mass"])["mass"], running[:, 0])  # the episodes go on
            True
            >>> first = env.reset()["domain", "mass"]  # the first draw of the seed
            >>> _ = env.set_seed(5)
            >>> torch.equal(env.reset()["domain", "mass"], first)
            True
        """
        self.generator = torch.Generator().manual_seed(check_int(seed, "DomainRandomization.set_seed: seed"))
        self.next_domain.zero_()
        if self.cycle_size is not None and not self._given_domains:
            self.domains_drawn.fill_(False)
        self.started = torch.zeros_like(self.started)
        self.steps = torch.zeros_like(self.steps)

    def seed_identity(self) -> str:
        """``"DomainRandomization(<field names>)"``: mixed into the seed ``env.set_seed`` derives for it."""
        return f"{type(self).__name__}({list(self.names)!r})"

    # ------------------------------------------------------------------ set-up
    def _forget_setup(self) -> None:
        self.__dict__.pop("_fields", None)
        self.__dict__.pop("_base", None)

    def _find_domain_env(self) -> DomainEnv | None:
        """The owners of the env's domain fields as one DomainEnv (:func:`~.domain_owners.domain_owners`): the base env
        itself when no transform owns fields (today's path, unchanged), a routing view over the base env and the owning
        transforms otherwise, ``None`` when nothing owns fields. Cached until the env changes."""
        known = self.__dict__.get("_base")
        if known is not None:
            return known
        env = container_env(self)
        home = self.home_transforms()
        before: list = []
        if home is not None:
            flat, position = home
            after = [type(t).__name__ for t in flat[position + 1 :] if isinstance(t, DomainEnv)]
            if after:
                raise ValueError(
                    f"DomainRandomization: {', '.join(after)}, which owns domain fields, comes after it in the env's "
                    "transforms: put it before the DomainRandomization. TorchRL runs the pre-reset hooks and inverse "
                    "calls last to first: an owner before the randomization applies the values drawn for a reset or a "
                    "step in that reset or step, and its fields' shapes are known when the randomization builds its "
                    "specs"
                )
            before = flat[:position]
        domain = domain_owners(getattr(env, "base_env", None), before, getattr(env, "batch_size", torch.Size()))
        if domain is not None:  # until the env changes (_forget_setup): an isinstance of a Protocol is slow
            self.__dict__["_base"] = domain
        return domain

    def _base_env(self) -> DomainEnv:
        """The DomainEnv the params' fields go to (:meth:`_find_domain_env`); ``TypeError`` when nothing owns fields."""
        domain = self._find_domain_env()
        if domain is None:
            base = getattr(container_env(self), "base_env", None)
            raise TypeError(
                "DomainRandomization: the base env must offer per-env physics (domain_fields, set_domain, "
                f"domain_values: a torchtasks BatchedMujocoEnv or PendulumEnv), got {type(base).__name__}, and no "
                "transform before the DomainRandomization owns domain fields (an ObservationNoise)"
            )
        return domain

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_base", None)  # derived from the env again where the copy lands
        state.pop("_fields", None)
        return state

    def _others(self) -> list[DomainRandomization]:
        home = self.home_transforms()
        if home is None:
            return []
        flat, position = home
        return [t for i, t in enumerate(flat) if i != position and isinstance(t, DomainRandomization)]

    def fields(self) -> list[DomainField]:
        """The base env's fields of the params, in order, each param bound to its field (its draws checked against the
        field's range); cached until the env changes. A writer of the params' buffers calls it before its checks."""
        return self._resolve()

    def unwritable_reason(self) -> str | None:
        """Why values written into the params' distributions would never be drawn; ``None`` if every draw follows them.

        Only ``when="reset"`` or ``"interval"`` without ``cycle`` draw from the distributions again and again:
        ``when="startup"`` draws once per env, a drawn ``cycle=K`` once for the run, a given ``cycle`` never. A
        :class:`~torchtasks.transforms.Curriculum` or :class:`~torchtasks.transforms.DifficultyLevels` refuses to set
        a distribution parameter of this transform when this says why.

        Example:
            >>> from torchtasks.domain import UniformDomainParam
            >>> params = [UniformDomainParam("mass", mean=1.0, halfspan=0.5)]
            >>> DomainRandomization(params).unwritable_reason() is None
            True
            >>> DomainRandomization(params, when="startup").unwritable_reason()
            "when='startup', which draws each env's values once, at its first reset"
        """
        if self.cycle_size is not None and self._given_domains:
            return f"cycle={{...}} ({self.cycle_size} stored domains given), which never draws from its distributions"
        if self.cycle_size is not None:
            return (
                f"cycle={self.cycle_size}, which draws its {self.cycle_size} stored domains once, at the first draw, "
                "and then gives them in turn"
            )
        if self.when == "startup":
            return "when='startup', which draws each env's values once, at its first reset"
        return None

    def _resolve(self) -> list[DomainField]:
        """The base env's fields of the params (checked: names, overlaps, shapes, ranges), cached until it changes."""
        fields = self.__dict__.get("_fields")
        if fields is not None:
            return fields
        base = self._base_env()
        others = [name for other in self._others() for name in other.names]
        clash = sorted(set(others) & set(self.names))
        if clash:
            raise ValueError(
                f"DomainRandomization: another DomainRandomization of the env also draws {clash}: a field has one owner"
            )
        fields = base.domain_fields([*self.names, *others])[: len(self.names)]  # refuses overlaps across transforms
        for param, field in zip(self.params.values(), fields, strict=True):
            param.bind_field(field)
        for name, field in zip(self.names, fields, strict=True):
            if self.cycle_size is not None and bool(self.domains_drawn):
                stored = self.domains._buffers[name]
                bad = ~field.allows(stored).reshape(len(stored), -1).all(-1)
                if bool(bad.any()):
                    row = int(bad.nonzero()[0, 0])
                    raise ValueError(
                        f"DomainRandomization: the stored domain {row} gives {name!r} the value "
                        f"{stored[row].tolist()}, "
                        f"but {name!r} ({field.description}) must be {field.rule}"
                    )
        self.__dict__["_fields"] = fields
        return fields

    def _make_state(self, batch: torch.Size, device: torch.device | None) -> None:
        """Give the per-env buffers the env's batch (the env's current values, no env started) unless they have it.

        Values the transform already holds for this batch (loaded before it was put into the env, or drawn in another
        env of the same batch) are given to the env now, so the data never reports physics the env does not run; held
        values of another batch are refused.
        """
        base = self._base_env()
        fields = self._resolve()
        if self.started.shape != batch:
            if bool(self.started.any()):
                raise ValueError(
                    f"DomainRandomization: it holds the drawn values of a batch {list(self.started.shape)} (loaded, or "
                    f"drawn in another env), but the env's batch is {list(batch)}: load a checkpoint of this batch"
                )
            self.started = torch.zeros(batch, dtype=torch.bool, device=device)
            self.steps = torch.zeros(batch, dtype=torch.int64, device=device)
        current = None
        for name, field in zip(self.names, fields, strict=True):
            if self.drawn._buffers[name].shape != batch + field.value_shape:
                current = base.domain_values(list(self.names)) if current is None else current
                self.drawn._buffers[name] = current[name].to(device=device, dtype=torch.float64).clone()
        if bool(self.started.any()):
            base.set_domain({name: self.drawn._buffers[name] for name in self.names}, self.started)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch, device = observation_spec.shape, observation_spec.device
        self._make_state(batch, device)
        for key, field in zip(self.__dict__["_keys"], self._resolve(), strict=True):
            shape = (*batch, *entry_shape(field.value_shape))
            observation_spec[key] = Unbounded(shape=shape, dtype=torch.float64, device=device)
        return observation_spec

    # ------------------------------------------------------------------ drawing
    def _draw(self, need: torch.Tensor) -> _Draw:
        """New values for the envs of ``need`` (bool ``[*B]``), the others' kept: one draw of every env per call.

        Fresh draws sample every env (the generator's use does not depend on which envs need values); a cycle
        gives the envs of ``need`` the next stored domains in index order. Nothing of the transform is written here:
        :meth:`_apply_draw` keeps the draw once the env has taken the values.
        """
        batch = need.shape
        domains = next_domain = None
        if self.cycle_size is None:
            new = {name: self._sample(param, batch) for name, param in self.params.items()}
        else:
            stored = {name: self.domains._buffers[name] for name in self.names}
            if not bool(self.domains_drawn):  # the first draw of the run: the stored set (a host fact, once)
                domains = {name: param.sample(self.cycle_size, self.generator) for name, param in self.params.items()}
                stored = domains
            flat = need.reshape(-1)
            rank = torch.cumsum(flat.to(torch.int64), 0) - 1
            index = (self.next_domain + rank).remainder(self.cycle_size)
            next_domain = (self.next_domain + flat.sum()).remainder(self.cycle_size)
            new = {
                name: stored[name].to(need.device)[index].reshape(batch + param.value_shape)
                for name, param in self.params.items()
            }
        values = {}
        for name, param in self.params.items():
            old, value = self.drawn._buffers[name], new[name]
            # a scalar field's mask is need itself, and a draw on the buffer's device stays there: each op skipped
            # is a few microseconds at every reset
            mask = need.reshape(batch + (1,) * len(param.value_shape)) if param.value_shape else need
            value = value if value.device == old.device else value.to(old.device)
            values[name] = torch.where(mask, value, old)
        return _Draw(values, domains, next_domain)

    def _sample(self, param: DomainParam, batch: torch.Size) -> torch.Tensor:
        values = param.sample(batch.numel(), self.generator)
        return values if len(batch) == 1 else values.reshape(batch + param.value_shape)

    def _apply_draw(self, need: torch.Tensor) -> None:
        """Draw for the envs of ``need`` and give the values to the base env (nothing when no env needs values: one
        host read, which the base env's write on the host needs anyway). A draw the env refuses changes nothing: the
        drawn values, the stored set and its index, the counters and the generator's place stay as they were."""
        if not bool(need.any()):
            return
        generator = self.generator
        before = torch.get_rng_state() if generator is None else generator.get_state()
        try:
            draw = self._draw(need)
            self._base_env().set_domain(draw.values, need)
        except Exception:
            if generator is None:
                torch.set_rng_state(before)
            else:
                generator.set_state(before)
            raise
        for name, value in draw.values.items():
            self.drawn._buffers[name] = value
        if draw.domains is not None:
            for name, values in draw.domains.items():
                self.domains._buffers[name].copy_(values)
            self.domains_drawn.fill_(True)
        if draw.next_domain is not None:
            self.next_domain.copy_(draw.next_domain)
        buffers = self._buffers  # written directly: nn.Module.__setattr__ costs more than the ops at every reset
        buffers["started"] = buffers["started"] | need
        if self.when == "interval":
            buffers["steps"] = torch.where(need, torch.zeros_like(buffers["steps"]), buffers["steps"])

    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        tensordict = super()._reset_env_preprocess(tensordict)
        env = container_env(self)
        if env is None:
            return tensordict
        # the reset's data has the env's batch (env.batch_size asks every transform: ~20 us at each reset)
        batch = env.batch_size if tensordict is None else tensordict.batch_size
        if self.started.shape != batch:
            self._make_state(batch, env.device)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is None:
            need = torch.ones(batch, dtype=torch.bool, device=self.started.device)
        else:
            need = reset.reshape(batch)
            need = need if need.device == self.started.device else need.to(self.started.device)
        if self.when != "reset":
            need = need & ~self.started
        with torch.no_grad():
            self._apply_draw(need)
        return tensordict

    def _entries(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write every env's current values under ``entry_key`` (a scalar field's ``[*B, 1]``, as TorchRL's reward):
        copies, so that no entry of a step shares storage with another's or with the run state."""
        scalars = self.__dict__.get("_scalars")
        if scalars is None:
            scalars = self.__dict__["_scalars"] = frozenset(n for n, p in self.params.items() if not p.value_shape)
        values = {}
        for name in self.names:
            value = self.drawn._buffers[name]
            values[(name,)] = (value.unsqueeze(-1) if name in scalars else value).clone()
        set_records(tensordict, key_parts(self.entry_key), values)
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._entries(tensordict_reset)

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Before the base env steps (TorchRL's ``inv``): with ``when="interval"``, draw for the envs whose ``every``
        steps since their last draw are done, so the step runs with the new values and its entries say so."""
        if self.when == "interval" and self.steps.numel():
            with torch.no_grad():
                self._apply_draw(self.steps >= self.every)
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.when == "interval":
            self.steps = self.steps + 1
        return self._entries(next_tensordict)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Leave stored data as it is: the drawn values are in it."""
        return tensordict

    # ------------------------------------------------------------------ checkpoints
    def _saved_configuration(self) -> dict[str, Any]:
        """The configuration a checkpoint must match: the params' kinds, the moments, the stored set and shard."""
        return {
            "params": {name: [type(param).__name__, param.roundint] for name, param in self.params.items()},
            "when": self.when,
            "every": self.every,
            "cycle": self.cycle_size,
            "shard": self.shard,
        }

    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        """Refuse the checkpoint of another randomization: other fields, kinds, moments or stored set."""
        saved = state_dict.get(prefix + "_extra_state")
        own = self.get_extra_state()
        keys = ("params", "when", "every", "cycle")
        if not isinstance(saved, Mapping) or not set(keys) <= set(saved):
            raise ValueError(
                "DomainRandomization.load_state_dict: the checkpoint has no DomainRandomization configuration "
                f"(_extra_state with {list(keys)}), got {saved!r}"
            )
        saved = {**saved, "shard": _as_shard(saved.get("shard"))}  # absent from older checkpoints: no shard
        differ = [key for key in (*keys, "shard") if saved[key] != own[key]]
        if differ:
            raise ValueError(
                "DomainRandomization.load_state_dict: the checkpoint is of another randomization ("
                + ", ".join(f"{key}: saved {saved[key]!r}, here {own[key]!r}" for key in differ)
                + "); build the DomainRandomization as saved"
            )
        for name, param in self.params.items():  # each param's checks, before anything of this transform is written
            head = f"{prefix}params.{name}."
            trial = copy.deepcopy(param)
            try:
                trial.load_state_dict(
                    {key[len(head) :]: value for key, value in state_dict.items() if key.startswith(head)}
                )
            except (RuntimeError, ValueError) as error:
                raise ValueError(
                    f"DomainRandomization.load_state_dict: the saved distribution of {name!r}: {error}"
                ) from None
        self._check_saved_generator(saved)

    def _prepare_load(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        # the per-env buffers take the saved shapes (a transform not yet in an env has empty ones)
        for module, head in ((self.drawn, "drawn."), (self, "")):
            for name in list(module._buffers):
                saved = state_dict.get(prefix + head + name)
                own = module._buffers[name]
                if isinstance(saved, torch.Tensor) and own is not None and saved.shape != own.shape:
                    module._buffers[name] = torch.empty(saved.shape, dtype=own.dtype, device=own.device)

    def _check_loaded(self) -> None:
        """Refuse loaded values the env would refuse; in a built env, give the env the loaded values at once."""
        batches = {self.drawn._buffers[name].shape[: self.started.dim()] for name in self.names}
        if batches != {self.started.shape} or self.steps.shape != self.started.shape:
            raise ValueError(
                "DomainRandomization.load_state_dict: the drawn values, 'started' and 'steps' must share one env "
                "batch, "
                f"got {sorted(map(list, batches))}, {list(self.started.shape)} and {list(self.steps.shape)}"
            )
        self._forget_setup()
        env = container_env(self)
        if env is None or self._find_domain_env() is None:
            return
        if self.started.numel() == 0 and env.batch_size.numel() != 0:
            return  # no env's values held (a non-strict load without them, before the env built its specs)
        if self.started.shape != env.batch_size:
            raise ValueError(
                f"DomainRandomization.load_state_dict: the checkpoint holds the values of a batch "
                f"{list(self.started.shape)}, but the env's batch is {list(env.batch_size)}"
            )
        for name, field in zip(self.names, self._resolve(), strict=True):
            values = self.drawn._buffers[name]
            if not bool(field.allows(values).all()):
                raise ValueError(
                    f"DomainRandomization.load_state_dict: the saved values of {name!r} leave its range "
                    f"({field.description} must be {field.rule}): {values.tolist()}"
                )
        self._base_env().set_domain(
            {name: self.drawn._buffers[name] for name in self.names},
            torch.ones(env.batch_size, dtype=torch.bool, device=self.started.device),
        )

    def __repr__(self) -> str:
        every = f", every={self.every}" if self.every is not None else ""
        cycle = f", cycle={self.cycle_size}" if self.cycle_size is not None else ""
        shard = f", shard={self.shard}" if self.shard is not None else ""
        return f"{type(self).__name__}({list(self.params.values())}, when={self.when!r}{every}{cycle}{shard})"


def _as_shard(saved: object) -> tuple[int, int] | None:
    """A saved shard as the tuple the constructor keeps (a checkpoint may hold a list)."""
    return tuple(saved) if isinstance(saved, list | tuple) else saved


def _check_shard(shard: object, cycle: object) -> tuple[int, int] | None:
    """``shard`` as ``(index, count)`` with ``0 <= index < count``, refused without given stored domains."""
    if shard is None:
        return None
    if not isinstance(shard, tuple | list) or len(shard) != 2:
        raise TypeError(
            "DomainRandomization: shard must be a pair (index, count) of ints: this worker's index among count "
            f"workers, got {shard!r}"
        )
    count = check_positive_int(shard[1], "DomainRandomization: shard[1] (the number of shards)")
    index = check_int(shard[0], "DomainRandomization: shard[0] (this shard's index)")
    if not 0 <= index < count:
        raise ValueError(f"DomainRandomization: shard=(index, count) needs 0 <= index < count, got {tuple(shard)}")
    if not isinstance(cycle, Mapping):
        raise ValueError(
            "DomainRandomization: shard splits given stored domains between workers and needs cycle={name: values}; "
            f"got cycle={cycle!r} (a set drawn with cycle=K is drawn by each worker from its own stream)"
        )
    return index, count


def entry_shape(value_shape: torch.Size) -> torch.Size:
    """The trailing shape of a field's entry: its value shape, ``[1]`` for a scalar (TorchRL's per-env scalars, such as
    ``"reward"``, are ``[*B, 1]``: they concatenate with observations into a network's input)."""
    return value_shape if len(value_shape) else torch.Size([1])
