"""Pushes and external forces per env at random intervals: :class:`Pushes`, a TorchRL transform.

IsaacLab and mjlab perturb a robot with interval events: ``push_by_setting_velocity`` adds a random
velocity to the root, ``apply_external_force_torque`` applies a random wrench. :class:`Pushes` does
both for a named body, per env, on a per-env timer, before the physics of the step it fires in, through
the small :class:`PushableEnv` protocol of the base env (a :class:`~torchtasks.envs.BatchedMujocoEnv`).
Its ranges are domain fields (``push_velocity:<body>``, ``push_force:<body>``): a
:class:`~torchtasks.transforms.DomainRandomization` draws them per env, a curriculum schedules them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import check_int, check_positive_int, did_you_mean
from torchtasks._memory import td_set
from torchtasks._torchrl import container_env, key_parts, nested_key
from torchtasks.domain import DomainField
from torchtasks.domain.fields import check_domain_values, select_fields
from torchtasks.transforms._base import EnvDerivedTransform
from torchtasks.transforms.names import PUSH_KEY, record_entry
from torchtasks.transforms.seeding import GeneratorTransform

__all__ = ["PushableEnv", "Pushes"]

#: the values of one push: 3 linear (force) then 3 angular (torque) components
PUSH_SIZE = 6
#: the kinds of push, by the domain field's prefix: (argument, entry, range buffer)
_KINDS = {
    "push_velocity": ("velocity", "velocity", "velocity_half_widths"),
    "push_force": ("force", "wrench", "force_half_widths"),
}
#: how far a number of seconds over the control timestep may lie from a whole number of steps and count as it
_STEP_TOLERANCE = 1e-9


@runtime_checkable
class PushableEnv(Protocol):
    """What a base env offers :class:`Pushes`: its pushable bodies, velocity changes and wrenches for masked envs.

    Example:
        >>> from torchtasks.envs import BatchedMujocoEnv, readings
        >>> xml = '''<mujoco><worldbody><body name="box"><freejoint/><geom size="0.1"/>
        ...   <body><joint name="hinge"/><geom size="0.05" pos="0 0 0.2"/></body></body></worldbody>
        ...   <actuator><motor joint="hinge"/></actuator></mujoco>'''
        >>> env = BatchedMujocoEnv(xml, 2, observation=readings.joint_pos("hinge"))
        >>> isinstance(env, PushableEnv), env.pushable_bodies()
        (True, ('box',))
    """

    #: the env's control timestep in seconds (one step)
    dt: float

    def pushable_bodies(self) -> tuple[str, ...]:
        """The bodies whose velocity a push can change (bodies with a free joint)."""
        ...

    def add_body_velocity(self, body: str, delta: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        """Add ``delta`` (float64 ``[num_envs, 6]``) to ``body``'s free-joint velocity in the envs of ``mask``."""
        ...

    def set_body_wrench(self, body: str, wrench: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        """Hold ``wrench`` (float64 ``[num_envs, 6]``) on ``body`` in the envs of ``mask`` until set again."""
        ...


class Pushes(CheckedLoad, GeneratorTransform, EnvDerivedTransform):
    """Push a body of every env at random intervals: a velocity change and/or a force held for some steps.

    Per env, a timer counts down the steps to the next push, drawn uniformly from ``interval_steps=(low, high)``
    (integers, inclusive) or from the whole numbers of steps in ``interval_seconds=(low, high)`` (with the env's
    control timestep ``dt``), at each env's reset and after each push. A push fires before the physics of the
    ``k``-th step (``k`` the drawn number), so that step starts from the pushed state and its observation shows it:
    ``velocity`` adds a change drawn uniformly per component in ``[-h, h]`` to the body's free-joint velocity
    (MuJoCo's: linear in the world frame, angular in the body frame); ``force`` applies a wrench drawn likewise
    (force then torque, world frame, at the body's centre of mass) for ``duration`` steps; a push during a force
    replaces it. ``h`` are 6 half-widths per env: the domain fields ``push_velocity:<body>`` and
    ``push_force:<body>`` (:meth:`domain_fields`), which a ``DomainRandomization`` may draw per env.

    Entries (float64 ``[*B, 6]``, observation spec): ``"<entry_key>_velocity"``, the change applied in the step
    (zeros elsewhere), and ``"<entry_key>_wrench"``, the wrench held during the step (leaves, not a node: a node
    costs TorchRL's step more; for a nested ``entry_key`` the last part takes the suffix). Run state (``state_dict``):
    the timers, the force's steps left, the wrench, the per-env half-widths and the generator, seeded per worker
    by ``env.set_seed``; a checkpoint of another body, kinds, duration or interval is refused. The draws, at each step
    where some env is pushed or a force ends, for all envs: uniforms ``u`` ``[*B, 6 per kind]`` (velocity columns
    first; a component is ``(2u - 1) h``), then timers ``[*B]``.

    Args:
        body: the body pushed (a free-joint body of ``env.pushable_bodies()`` for ``velocity``).
        velocity: 6 half-widths ``>= 0`` of the velocity change (m/s, rad/s), or ``None``.
        force: 6 half-widths ``>= 0`` of the wrench (N, N m), or ``None``.
        duration: the steps a force is held (``>= 1``).
        interval_steps: the steps between pushes, an int or an inclusive ``(low, high)`` with ``1 <= low <= high``.
        interval_seconds: or that range in seconds, ``0 < low <= high`` (one of the two).
        entry_key: the prefix of the entries' keys (``"push"``: ``"push_velocity"``, ``"push_wrench"``).
        seed: seed of the transform's own generator (``None``: torch's global one until ``env.set_seed``).

    Example:
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.envs import BatchedMujocoEnv, readings
        >>> from torchtasks.transforms import Pushes
        >>> xml = '''<mujoco><worldbody><body name="box"><freejoint/><geom size="0.1"/>
        ...   <body><joint name="hinge"/><geom size="0.05" pos="0 0 0.2"/></body></body></worldbody>
        ...   <actuator><motor joint="hinge"/></actuator></mujoco>'''
        >>> base = BatchedMujocoEnv(xml, 3, observation=readings.joint_pos("hinge"), seed=0)
        >>> pushes = Pushes("box", velocity=[0.5, 0.5, 0.0, 0.0, 0.0, 1.0], interval_steps=(2, 4), seed=0)
        >>> env = TransformedEnv(base, Compose(StepCounter(10), pushes))
        >>> rollout = env.rollout(8)
        >>> pushed = rollout["next", "push_velocity"].abs().sum(-1) > 0  # [3 envs, 8 steps]
        >>> pushed.sum(-1).tolist()  # every env: 2 to 4 pushes in 8 steps
        [2, 2, 2]
        >>> [field.name for field in pushes.domain_fields()]  # schedulable ranges
        ['push_velocity:box']
    """

    def __init__(
        self,
        body: str,
        *,
        velocity: Sequence[float] | torch.Tensor | None = None,
        force: Sequence[float] | torch.Tensor | None = None,
        duration: int = 1,
        interval_steps: int | tuple[int, int] | None = None,
        interval_seconds: tuple[float, float] | None = None,
        entry_key: str | tuple[str, ...] = PUSH_KEY,
        seed: int | None = None,
    ) -> None:
        if not isinstance(body, str) or not body:
            raise TypeError(f"Pushes: body must be a body's name (a non-empty str), got {body!r}")
        if "." in body or "/" in body:
            raise ValueError(
                f"Pushes: body {body!r} holds '.' or '/', which its domain fields' names (push_velocity:<body>) cannot "
                "hold: targets and entries use them as separators; rename the body in the model"
            )
        nominal = {}
        for kind, value in (("push_velocity", velocity), ("push_force", force)):
            if value is not None:
                nominal[kind] = _half_widths(value, f"Pushes: {_KINDS[kind][0]}")
        if not nominal:
            raise ValueError("Pushes: give velocity= (half-widths of a velocity change) and/or force= (of a wrench)")
        self.duration = check_positive_int(duration, "Pushes: duration")
        self.interval_steps, self.interval_seconds = _interval(interval_steps, interval_seconds)
        self.entry_key = nested_key(entry_key, "Pushes: entry_key")
        keys = {kind: record_entry(key_parts(self.entry_key), _KINDS[kind][1]) for kind in nominal}
        super().__init__(in_keys=[], out_keys=list(keys.values()))
        self.body = body
        #: the domain field's name by kind (``"push_velocity"``) and the entry each kind writes
        self.field_names = {kind: f"{kind}:{body}" for kind in nominal}
        self.__dict__["_keys"] = keys
        #: the given half-widths by kind (float64 ``[6]``): the fields' nominal values
        self.nominal = nominal
        #: steps until each env's next push (``[*B]``; 0 before the first reset: a push at the first step)
        self.register_buffer("steps_left", torch.empty(0, dtype=torch.int64))
        for kind in nominal:  # each env's half-widths: the domain fields' values
            self.register_buffer(_KINDS[kind][2], torch.empty(0, dtype=torch.float64))
        if "push_force" in nominal:
            #: steps each env's wrench is still held, this one included, and the wrench
            self.register_buffer("force_steps_left", torch.empty(0, dtype=torch.int64))
            self.register_buffer("wrench", torch.empty(0, dtype=torch.float64))
        if "push_velocity" in nominal:  # the change applied in the step being taken: data, not run state
            self.register_buffer("applied_velocity", torch.empty(0, dtype=torch.float64), persistent=False)
        self.generator = None if seed is None else torch.Generator().manual_seed(check_int(seed, "Pushes: seed"))

    # ------------------------------------------------------------------ seeding
    def set_seed(self, seed: int) -> None:
        """Seed the transform's own generator with ``seed``; the running timers and forces go on.

        ``env.set_seed(s)`` calls it with a seed derived from ``s`` (:mod:`torchtasks.transforms.seeding`); the seed
        decides the draws from then on (a run repeats from its first frame when it is reset after the seed).
        """
        self.generator = torch.Generator().manual_seed(check_int(seed, "Pushes.set_seed: seed"))

    def seed_identity(self) -> str:
        """``"Pushes(<body>, <entry key>)"``: mixed into the seed ``env.set_seed`` derives for it."""
        return f"{type(self).__name__}({self.body!r}, {self.entry_key!r})"

    # ------------------------------------------------------------------ set-up
    def _forget_setup(self) -> None:
        self.__dict__.pop("_pushed_env", None)
        self.__dict__.pop("_steps_range", None)

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_pushed_env", None)  # derived from the env again where the copy lands
        return state

    def _pushable_env(self) -> PushableEnv:
        """The base env, checked once per env: a :class:`PushableEnv` that can push ``body`` as configured."""
        known = self.__dict__.get("_pushed_env")
        if known is not None:
            return known
        base = getattr(container_env(self), "base_env", None)
        if not isinstance(base, PushableEnv):
            raise TypeError(
                "Pushes: the base env must offer pushable_bodies, add_body_velocity, set_body_wrench and dt (a "
                f"torchtasks BatchedMujocoEnv), got {type(base).__name__}"
            )
        bodies = tuple(base.pushable_bodies())
        if "push_velocity" in self.nominal and self.body not in bodies:
            raise ValueError(
                f"Pushes: body {self.body!r} has no free joint in the env, so its velocity cannot be pushed"
                f"{did_you_mean(self.body, list(bodies), n=3, cutoff=0.5)} (the pushable bodies: {list(bodies)})"
            )
        if "push_force" in self.nominal:  # the env checks the name: a write to no env
            batch = container_env(self).batch_size
            nothing = torch.zeros(batch, dtype=torch.bool)
            base.set_body_wrench(self.body, torch.zeros(*batch, PUSH_SIZE, dtype=torch.float64), nothing)
        self.__dict__["_pushed_env"] = base  # until the env changes (_forget_setup): a Protocol's isinstance is slow
        return base

    def steps_range(self) -> tuple[int, int]:
        """The inclusive range of steps between pushes (``interval_seconds`` converted with the env's ``dt``).

        The steps of a range in seconds are the whole numbers ``k >= 1`` with ``low <= k * dt <= high``; a range
        that holds none is a ``ValueError``.
        """
        if self.interval_steps is not None:
            return self.interval_steps
        known = self.__dict__.get("_steps_range")
        if known is not None:
            return known
        dt = float(self._pushable_env().dt)
        low_s, high_s = self.interval_seconds
        low, high = math.ceil(low_s / dt - _STEP_TOLERANCE), math.floor(high_s / dt + _STEP_TOLERANCE)
        if low < 1 or low > high:
            raise ValueError(
                f"Pushes: interval_seconds={self.interval_seconds} holds no whole number of steps >= 1 of the env's "
                f"control timestep dt={dt} s (it gives {low} to {high}); widen it or give interval_steps"
            )
        self.__dict__["_steps_range"] = (low, high)
        return low, high

    def _make_state(self, batch: torch.Size, device: torch.device | None) -> None:
        """Size the per-env buffers for ``batch`` (the nominal half-widths, no timer, no wrench), unless they are."""
        if self.steps_left.shape == batch:
            return
        buffers = self._buffers
        buffers["steps_left"] = torch.zeros(batch, dtype=torch.int64, device=device)
        for kind, value in self.nominal.items():
            buffers[_KINDS[kind][2]] = value.to(device).expand(*batch, PUSH_SIZE).clone()
        if "push_force" in self.nominal:
            buffers["force_steps_left"] = torch.zeros(batch, dtype=torch.int64, device=device)
            buffers["wrench"] = torch.zeros(*batch, PUSH_SIZE, dtype=torch.float64, device=device)
        if "push_velocity" in self.nominal:
            buffers["applied_velocity"] = torch.zeros(*batch, PUSH_SIZE, dtype=torch.float64, device=device)

    def _batch(self) -> torch.Size:
        """The env batch of the per-env buffers, made now from the env if the specs were not built yet."""
        if self.steps_left.numel() == 0:
            env = container_env(self)
            if env is None:
                raise ValueError("Pushes: the per-env ranges need the env's batch; put the transform into an env first")
            self._make_state(env.batch_size, env.device)
        return self.steps_left.shape

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch, device = observation_spec.shape, observation_spec.device
        self._make_state(batch, device)
        if container_env(self) is not None:  # check the body and the interval against the env now
            self._pushable_env()
            self.steps_range()
        for key in self.__dict__["_keys"].values():
            observation_spec[key] = Unbounded(shape=(*batch, PUSH_SIZE), dtype=torch.float64, device=device)
        return observation_spec

    # ------------------------------------------------------------------ domain fields (the DomainEnv protocol)
    def domain_fields(self, names: Sequence[str] | None = None) -> list[DomainField]:
        """The push ranges as domain fields: ``push_velocity:<body>`` and/or ``push_force:<body>``.

        Each is 6 half-widths (float64 ``[6]``, in ``[0, inf)``), nominal the ones given to the constructor; unknown
        names are a ``ValueError`` naming the close ones.

        Example:
            >>> pushes = Pushes("torso", velocity=[0.5, 0.5, 0, 0, 0, 0], force=[10.0] * 6, interval_steps=50)
            >>> [(field.name, field.rule) for field in pushes.domain_fields()]
            [('push_velocity:torso', 'in [0.0, inf)'), ('push_force:torso', 'in [0.0, inf)')]
        """
        return select_fields(self._field_table(), names, self._owner(), kinds="push_velocity:<body>, push_force:<body>")

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give the envs of ``mask`` the half-widths ``values[name][i]`` (float64 ``[num_envs, 6]``), from their next
        push on (a push under way keeps its draw). Rows outside ``mask`` are ignored; the others must be finite and
        ``>= 0`` (``ValueError`` naming the field, the env and the value).

        Example:
            >>> import torch
            >>> from torchrl.envs import TransformedEnv
            >>> from torchtasks.envs import BatchedMujocoEnv
            >>> pushes = Pushes("torso", velocity=[0.5] * 6, interval_steps=(5, 10))
            >>> env = TransformedEnv(BatchedMujocoEnv("Ant-v5", num_envs=2), pushes)
            >>> wider = torch.tensor([[1.0] * 6, [2.0] * 6], dtype=torch.float64)
            >>> pushes.set_domain({"push_velocity:torso": wider}, torch.tensor([False, True]))
            >>> pushes.domain_values()["push_velocity:torso"][:, 0].tolist()
            [0.5, 2.0]
        """
        batch = self._batch()
        rows = check_domain_values(self._field_table(), values, mask, batch, self._owner())
        for name, value in values.items():
            buffer = self._buffers[_KINDS[name.split(":")[0]][2]]
            where = rows.to(buffer.device).reshape(*batch, 1)
            buffer.copy_(torch.where(where, value.to(buffer.device), buffer))

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's half-widths of each field named (``None``: all), float64 ``[num_envs, 6]`` (copies)."""
        self._batch()
        fields = select_fields(self._field_table(), names, self._owner())
        return {field.name: self._buffers[_KINDS[field.name.split(":")[0]][2]].clone() for field in fields}

    def _field_table(self) -> dict[str, DomainField]:
        table = {}
        for kind, nominal in self.nominal.items():
            what = "velocity change (m/s linear, world frame; rad/s angular, body frame)"
            if kind == "push_force":
                what = "wrench (N force, N m torque; world frame, at the centre of mass)"
            name = self.field_names[kind]
            table[name] = DomainField(
                name=name,
                value_shape=torch.Size([PUSH_SIZE]),
                nominal=nominal,
                low=0.0,
                high=math.inf,
                low_open=False,
                model_fields=(),
                set_const=False,
                description=f"half-widths of the {what} of a push of body {self.body!r}",
            )
        return table

    def _owner(self) -> str:
        return f"Pushes({self.body!r})"

    # ------------------------------------------------------------------ TorchRL hooks
    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        """Draw each reset env's timer; its force is gone (the env's reset cleared the wrench)."""
        batch = tensordict_reset.batch_size
        device = self.steps_left.device
        self._make_state(batch, device)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        mask = torch.ones(batch, dtype=torch.bool, device=device) if reset is None else reset.reshape(batch)
        mask = mask.to(device)
        low, high = self.steps_range()
        buffers = self._buffers  # written directly: nn.Module.__setattr__ costs more than the ops at every reset
        with torch.no_grad():
            timers = torch.randint(low, high + 1, batch, generator=self.generator).to(device)
            buffers["steps_left"] = torch.where(mask, timers, buffers["steps_left"])
            if "push_force" in self.nominal:
                buffers["force_steps_left"] = buffers["force_steps_left"].masked_fill(mask, 0)
                buffers["wrench"] = buffers["wrench"].masked_fill(mask.unsqueeze(-1), 0.0)
            if "push_velocity" in self.nominal:
                buffers["applied_velocity"].zero_()
        return self._entries(tensordict_reset)

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Before the base env steps (TorchRL's ``inv``): count down, and push the envs whose timer ran out."""
        buffers = self._buffers
        if buffers["steps_left"].numel() == 0:
            return tensordict
        with torch.no_grad():
            steps_left = buffers["steps_left"]
            steps_left.sub_(1)
            fired = steps_left <= 0
            changed, ending = fired, None
            if "push_force" in self.nominal:
                held = buffers["force_steps_left"]
                ending = held == 1
                held.sub_(1).clamp_(min=0)
                changed = fired | ending
            if "push_velocity" in self.nominal:
                buffers["applied_velocity"].zero_()
            if bool(changed.any()):  # the one host read of a step
                self._push(fired, ending)
        return tensordict

    def _push(self, fired: torch.Tensor, ending: torch.Tensor | None) -> None:
        """Push the envs of ``fired``, end the forces of ``ending``, and draw the fired envs' next timers."""
        env, buffers, generator = self._pushable_env(), self._buffers, self.generator
        batch, device = fired.shape, fired.device
        column = fired.unsqueeze(-1)
        # one draw for the kinds, velocity columns first: 2u - 1 in [-1, 1) per component, scaled by each env's h
        unit = torch.rand(*batch, PUSH_SIZE * len(self.nominal), generator=generator, dtype=torch.float64)
        signed = unit.to(device).mul_(2.0).sub_(1.0)
        if "push_velocity" in self.nominal:
            delta = torch.where(column, signed[..., :PUSH_SIZE] * buffers["velocity_half_widths"], 0.0)
            env.add_body_velocity(self.body, delta, fired)
            buffers["applied_velocity"] = delta
        if "push_force" in self.nominal:
            drawn = signed[..., -PUSH_SIZE:] * buffers["force_half_widths"]
            ended = buffers["wrench"].masked_fill(ending.unsqueeze(-1), 0.0)  # type: ignore[union-attr]
            wrench = torch.where(column, drawn, ended)
            env.set_body_wrench(self.body, wrench, fired | ending)
            buffers["wrench"] = wrench
            buffers["force_steps_left"] = buffers["force_steps_left"].masked_fill(fired, self.duration)
        low, high = self.steps_range()
        timers = torch.randint(low, high + 1, batch, generator=generator).to(device)
        buffers["steps_left"] = torch.where(fired, timers, buffers["steps_left"])

    def _entries(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write copies of this step's velocity change and wrench (no entry of a step shares storage with the state)."""
        keys = self.__dict__["_keys"]
        if "push_velocity" in keys:
            td_set(tensordict, keys["push_velocity"], self._buffers["applied_velocity"].clone())
        if "push_force" in keys:
            td_set(tensordict, keys["push_force"], self._buffers["wrench"].clone())
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._entries(next_tensordict)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Leave stored data as it is: the pushes are in it."""
        return tensordict

    # ------------------------------------------------------------------ checkpoints
    def _configuration(self) -> dict[str, Any]:
        return {
            "body": self.body,
            "kinds": sorted(self.nominal),
            "half_widths_shape": [PUSH_SIZE],
            "duration": self.duration,
            "interval_steps": None if self.interval_steps is None else list(self.interval_steps),
            "interval_seconds": None if self.interval_seconds is None else list(self.interval_seconds),
        }

    def _saved_configuration(self) -> dict[str, Any]:
        """The configuration a checkpoint must match, under ``"configuration"``."""
        return {"configuration": self._configuration()}

    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        """Refuse the checkpoint of other pushes: another body, kinds, ranges' shape, duration or interval."""
        saved = state_dict.get(prefix + "_extra_state")
        configuration = saved.get("configuration") if isinstance(saved, Mapping) else None
        own = self._configuration()
        if not isinstance(configuration, Mapping) or set(configuration) != set(own):
            raise ValueError(
                "Pushes.load_state_dict: the checkpoint has no Pushes configuration (_extra_state with "
                f"'configuration': {sorted(own)}), got {saved!r}"
            )
        differ = [key for key in own if configuration[key] != own[key]]
        if differ:
            raise ValueError(
                "Pushes.load_state_dict: the checkpoint is of other pushes ("
                + ", ".join(f"{key}: saved {configuration[key]!r}, here {own[key]!r}" for key in differ)
                + "); build the Pushes as saved"
            )
        self._check_saved_generator(saved)

    def _prepare_load(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        # the per-env buffers take the saved shapes (a transform not yet in an env has empty ones)
        for name, own in list(self._buffers.items()):
            saved = state_dict.get(prefix + name)
            if isinstance(saved, torch.Tensor) and own is not None and saved.shape != own.shape:
                self._buffers[name] = torch.empty(saved.shape, dtype=own.dtype, device=own.device)
        if "push_velocity" in self.nominal:  # not saved: sized like the loaded timers
            steps = state_dict.get(prefix + "steps_left")
            if isinstance(steps, torch.Tensor):
                own = self._buffers["applied_velocity"]
                self._buffers["applied_velocity"] = torch.zeros(
                    *steps.shape, PUSH_SIZE, dtype=own.dtype, device=own.device
                )

    def _check_loaded(self) -> None:
        """Refuse loaded state the constructor or the env would refuse: batches that differ, values out of range."""
        buffers = self._buffers
        batch = buffers["steps_left"].shape
        for kind in self.nominal:
            name = _KINDS[kind][2]
            values = buffers[name]
            if values.shape != (*batch, PUSH_SIZE) and not (values.numel() == 0 and batch.numel() == 0):
                raise ValueError(
                    f"Pushes.load_state_dict: {name!r} must have shape {[*batch, PUSH_SIZE]} (the timers' batch "
                    f"{list(batch)}, 6 half-widths), got {list(values.shape)}"
                )
            if not bool((torch.isfinite(values) & (values >= 0)).all()):
                raise ValueError(f"Pushes.load_state_dict: the saved {name!r} must be finite and >= 0")
        if bool((buffers["steps_left"] < 0).any()):
            raise ValueError("Pushes.load_state_dict: the saved 'steps_left' must be >= 0")
        if "push_force" in self.nominal:
            held, wrench = buffers["force_steps_left"], buffers["wrench"]
            if held.shape != batch or (wrench.shape != (*batch, PUSH_SIZE) and batch.numel() != 0):
                raise ValueError(
                    f"Pushes.load_state_dict: 'force_steps_left' and 'wrench' must have shapes {list(batch)} and "
                    f"{[*batch, PUSH_SIZE]} (the timers' batch), got {list(held.shape)} and {list(wrench.shape)}"
                )
            if not bool(((held >= 0) & (held <= self.duration)).all()) or not bool(torch.isfinite(wrench).all()):
                raise ValueError(
                    f"Pushes.load_state_dict: the saved 'force_steps_left' must be in [0, {self.duration}] (duration) "
                    "and the saved 'wrench' finite"
                )
        env = container_env(self)
        if env is not None and batch.numel() != 0 and batch != env.batch_size:
            raise ValueError(
                f"Pushes.load_state_dict: the checkpoint holds the pushes of a batch {list(batch)}, but the env's "
                f"batch is {list(env.batch_size)}"
            )

    def __repr__(self) -> str:
        kinds = ", ".join(f"{_KINDS[kind][0]}={value.tolist()}" for kind, value in self.nominal.items())
        interval = (
            f"interval_steps={self.interval_steps}"
            if self.interval_steps is not None
            else f"interval_seconds={self.interval_seconds}"
        )
        return f"{type(self).__name__}({self.body!r}, {kinds}, duration={self.duration}, {interval})"


def _half_widths(value: object, name: str) -> torch.Tensor:
    """``value`` as float64 ``[6]`` half-widths, finite and ``>= 0`` (else Type/ValueError naming ``name``)."""
    if isinstance(value, torch.Tensor):
        if not value.dtype.is_floating_point:
            raise TypeError(
                f"{name} must be 6 real half-widths (a float tensor or a sequence), got dtype {value.dtype}"
            )
        tensor = value.detach().to("cpu", torch.float64)
    elif isinstance(value, Sequence) and not isinstance(value, str):
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            raise TypeError(f"{name} must be 6 real half-widths, got {value!r}")
        tensor = torch.tensor([float(v) for v in value], dtype=torch.float64)
    else:
        raise TypeError(f"{name} must be 6 half-widths (a sequence or a float tensor) or None, got {value!r}")
    if tensor.shape != (PUSH_SIZE,):
        raise ValueError(
            f"{name} must hold 6 half-widths (3 linear, 3 angular components), got shape {list(tensor.shape)}"
        )
    if not bool((torch.isfinite(tensor) & (tensor >= 0)).all()):
        raise ValueError(f"{name} must be finite half-widths >= 0, got {tensor.tolist()}")
    return tensor.clone()


def _interval(steps: object, seconds: object) -> tuple[tuple[int, int] | None, tuple[float, float] | None]:
    """The checked interval: ``(steps, None)`` or ``(None, seconds)``, exactly one given."""
    if (steps is None) == (seconds is None):
        raise ValueError(
            "Pushes: give exactly one of interval_steps=(low, high) (steps) and interval_seconds=(low, high) "
            f"(seconds), got interval_steps={steps!r}, interval_seconds={seconds!r}"
        )
    if steps is not None:
        if isinstance(steps, Sequence) and not isinstance(steps, str):
            if len(steps) != 2:
                raise TypeError(f"Pushes: interval_steps must be an int or a (low, high) pair, got {steps!r}")
            low = check_int(steps[0], "Pushes: interval_steps[0]")
            high = check_int(steps[1], "Pushes: interval_steps[1]")
        else:
            low = high = check_int(steps, "Pushes: interval_steps")
        if low < 1 or low > high:
            raise ValueError(f"Pushes: interval_steps (low, high) needs 1 <= low <= high, got {steps!r}")
        return (low, high), None
    if not isinstance(seconds, Sequence) or isinstance(seconds, str) or len(seconds) != 2:
        raise TypeError(f"Pushes: interval_seconds must be a (low, high) pair of seconds, got {seconds!r}")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in seconds):
        raise TypeError(f"Pushes: interval_seconds must be a (low, high) pair of real numbers, got {seconds!r}")
    low_s, high_s = float(seconds[0]), float(seconds[1])
    if not (math.isfinite(high_s) and 0.0 < low_s <= high_s):
        raise ValueError(f"Pushes: interval_seconds (low, high) needs 0 < low <= high, finite, got {seconds!r}")
    return None, (low_s, high_s)
