"""Batched Gymnasium MuJoCo v5 locomotion envs in one process, stepped by ``mujoco.batch`` in one C call.

:class:`BatchedMujocoEnv` steps ``num_envs`` copies of a Gymnasium v5 locomotion env (HalfCheetah,
Hopper, Walker2d, Swimmer, Ant, Humanoid) as one TorchRL env with ``batch_size=[num_envs]``. The
model is the one Gymnasium builds for the same keyword arguments; the simulations are the rows of one
``mujoco.batch.Batch``: a step writes ``ctrl = action`` into the bound control rows and advances
every env ``frame_skip`` MuJoCo substeps in one call (C threads, GIL released), and the observation
is computed for all envs at once from the bound ``(num_envs, ...)`` arrays, exactly as Gymnasium v5
computes it for one env. Rewards and terminations come from a task: the env writes the entries
:func:`~torchtasks.envs.locomotion.locomotion_state_layout` lists, so
``TaskTransform(locomotion_task(env_id, **kw), state_key=[...])`` reproduces Gymnasium's reward, its
terms and its ``terminated`` (``gymnasium_env(env_id, num_envs=N)`` builds that stack).

Why ``mujoco.batch`` and not ``mujoco.rollout`` or threads over ``mj_step``: a batch keeps each
simulation as its ``mjSTATE_INTEGRATION`` row, the constraint solver's warm start included, so it
continues a Gymnasium trajectory bit for bit (``rollout`` does not return the final warm start, and
trajectories restarted from another one part within ~150 steps); and it steps, resets and reads all
envs in one call, where a Python thread pool paid a GIL hand-off and a gather per env
(``benchmarks/batched_mujoco.py`` measures the floors).
"""

from __future__ import annotations

import copy
import hashlib
import os
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, Transform

from torchtasks._checks import check_positive_int
from torchtasks._optional import missing_extra
from torchtasks._torchrl import container_env

try:
    import mujoco
    from mujoco.batch import Batch
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.batched_mujoco (BatchedMujocoEnv)", _error) from _error

from torchtasks.domain.fields import DomainField
from torchtasks.envs.gymnasium_v5 import LocomotionEnvRecord, ModelFacts, gymnasium_config, locomotion_record
from torchtasks.envs.mujoco_domain import BatchDomain, FieldKind

__all__ = ["BatchedMujocoEnv", "ZeroBrokenStepReward"]

#: the entry that marks a broken step (bool ``[num_envs, 1]``, observation spec)
BROKEN_KEY = "broken"

#: MuJoCo warnings raised when it resets a diverged state itself (mj_checkPos/Vel/Acc), consecutive in mjtWarning: a
#: slice of the warning counters is a view, read without a copy at every step
_DIVERGENCE_WARNINGS = slice(int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADQACC) + 1)
if _DIVERGENCE_WARNINGS.stop - _DIVERGENCE_WARNINGS.start != 3:  # pragma: no cover - a MuJoCo that reorders them
    raise ImportError(
        "torchtasks.envs.batched_mujoco: this MuJoCo's mjtWarning does not list mjWARN_BADQPOS, "
        "mjWARN_BADQVEL, mjWARN_BADQACC in a row; it is not supported"
    )
#: the column of ``Batch.warning`` (``[num_envs, mjNWARNING, 2]``: ``lastinfo``, ``number``) that counts
_WARNING_NUMBER = 1
#: what a checkpoint, a copy or a pickle of the env keeps of each simulation (a ``Batch`` state row): everything
#: ``mj_step`` starts from (time, qpos, qvel, act, the constraint solver's warm start, ctrl, applied forces, mocap,
#: ...), so a restored env continues the same trajectory bit for bit
_INTEGRATION_STATE = int(mujoco.mjtState.mjSTATE_INTEGRATION)
#: the entries of the running-episode state (``state_dict()["_extra_state"]["running_episodes"]``)
_RUNNING_KEYS = ("model", "integration_state", "warnings", "time", "previous_position", "gathered")
#: the entry of the per-env physics (the values of every domain field ever set), absent from checkpoints written
#: before the env had one (they load as nominal physics)
_DOMAIN_KEY = "domain"
#: attributes rebuilt when a copy or a pickle is restored: the batch (its C threads and state rows, restored from
#: the integration states on the one MjModel) and the bound arrays, buffers and observation plan (numpy views of
#: the batch and of each other, which a copy would turn into independent arrays)
_REBUILT = (
    "batch",
    "_qpos",
    "_qvel",
    "_clock",
    "_ctrl",
    "_physics",
    "_warnings",
    "_readers",
    "_contact_forces",
    "_scratch",
    "_observation_plan",
    "_entry_sources",
    "_position",
    "_mass_weights",
    "_domain",
    "_env_models",
)


def _check_state_keys(task_state_keys: object, record: LocomotionEnvRecord) -> tuple[str, ...]:
    """Return ``task_state_keys`` as a tuple; raise unless it names distinct task-state entries the env can write."""
    if isinstance(task_state_keys, (str, bytes)) or not isinstance(task_state_keys, Sequence):
        raise TypeError(f"task_state_keys must be a sequence of entry names, got {task_state_keys!r}")
    keys = tuple(task_state_keys)
    known = (*record.velocity_keys, "qpos", "qvel", "cfrc_ext")
    if not keys or len(set(keys)) != len(keys) or not all(isinstance(key, str) and key in known for key in keys):
        raise ValueError(
            f"task_state_keys must be distinct names among {list(known)} ({record.env_id}), got {list(keys)!r}"
        )
    return keys


def _default_threads() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


class BatchedMujocoEnv(EnvBase):
    """Step ``num_envs`` Gymnasium MuJoCo v5 locomotion envs in one process with native threads.

    One ``mujoco.MjModel`` (Gymnasium's, for ``env_id`` and ``gym_kwargs``) and one ``mujoco.batch.Batch`` of
    ``num_envs`` simulations of it (``env.batch``). A step sets ``ctrl = action`` (not clipped, as Gymnasium),
    advances every env by ``frame_skip`` substeps in one ``Batch.step`` call on ``num_threads`` threads and computes
    Gymnasium v5's observation for all envs: equal to Gymnasium's bit for bit on the same states. It writes
    ``"observation"`` and the task state (``"x_velocity"``, ``"qpos"``, ... of
    :func:`~torchtasks.envs.locomotion.locomotion_state_layout`), float64 ``[num_envs, size]``. It pays no reward and
    ends no episode (put the locomotion task's :class:`~torchtasks.transforms.TaskTransform` on it, or use
    ``gymnasium_env(env_id, num_envs=N)``), except a broken step (a non-finite action, a diverged state): that env
    ends, with ``"broken"`` set, a finite state and a ``RuntimeWarning`` (:class:`ZeroBrokenStepReward` pays 0 for
    it). Resets draw Gymnasium's initial states from one generator per env, for the masked envs only.
    ``state_dict()`` holds the generators and the running episodes: a load continues them bit for bit (in a
    ``TransformedEnv``, a :class:`~torchtasks.transforms.BaseEnvState` saves it with the transforms); copies and
    pickles are independent envs in the same state. As a :class:`~torchtasks.domain.DomainEnv` it gives each env its
    own physics (:meth:`set_domain`). Details: the docs page "The batched MuJoCo env".

    Args:
        env_id: one of :data:`~torchtasks.envs.locomotion.SUPPORTED_ENV_IDS`.
        num_envs: number of environments.
        seed: seed of the per-env generators (``set_seed`` reseeds them); ``None``: fresh entropy.
        device: device of the output tensors (the simulation runs on the CPU); ``env.to(device)`` moves them.
        num_threads: threads that step the envs (the calling thread included); default: the CPUs this process may
            use, at most ``num_envs``.
        task_state_keys: the task-state entries to write, in order (default: the env record's ``state_keys``, what
            :func:`~torchtasks.envs.locomotion.locomotion_task` reads).
        **gym_kwargs: the env's Gymnasium keyword arguments, validated as by
            :func:`~torchtasks.envs.locomotion.locomotion_task`. Rendering is not supported.

    Example:
        >>> from torchtasks.envs import BatchedMujocoEnv
        >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=2, seed=0)
        >>> rollout = env.rollout(3)
        >>> rollout["next", "observation"].shape, rollout["next", "qpos"].dtype
        (torch.Size([2, 3, 11]), torch.float64)
        >>> nominal, heavy = (BatchedMujocoEnv("Hopper-v5", num_envs=2, seed=0) for _ in range(2))
        >>> heavy.set_domain({"body_mass_scale": torch.tensor([1.0, 1.5], dtype=torch.float64)})  # env 1: 1.5 x
        >>> still = lambda td: td.set("action", torch.zeros(2, 3))
        >>> same = nominal.rollout(20, still)["next", "qpos"] == heavy.rollout(20, still)["next", "qpos"]
        >>> bool(same[0].all()), bool(same[1].all())
        (True, False)
        >>> for e in (env, nominal, heavy): e.close()
    """

    batch_locked = True
    #: ``frame_skip`` is MuJoCo's substeps per step, done in ``_step`` (TorchRL must not add a FrameSkipTransform)
    _has_frame_skip = True

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        seed: int | None = None,
        device: torch.device | str | None = None,
        num_threads: int | None = None,
        task_state_keys: Sequence[str] | None = None,
        _checked: tuple[dict[str, Any], ModelFacts] | None = None,
        **gym_kwargs: Any,
    ) -> None:
        # _checked: the keywords already validated by gymnasium_config and the facts of a Gymnasium env made with
        # them (gymnasium_env passes the ones it read, so that one Gymnasium env is made and the keywords checked once)
        record = locomotion_record(env_id)
        config = gymnasium_config(env_id, gym_kwargs) if _checked is None else _checked[0]
        num_envs = check_positive_int(num_envs, "num_envs")
        num_threads = min(
            _default_threads() if num_threads is None else check_positive_int(num_threads, "num_threads"), num_envs
        )
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise TypeError(f"seed must be an int or None, got {seed!r}")
        if config.get("render_mode") is not None:
            raise ValueError(f"BatchedMujocoEnv does not render; got render_mode={config['render_mode']!r}")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.env_id = env_id
        self.num_envs = num_envs
        self.num_threads = num_threads
        self.gym_kwargs = dict(gym_kwargs)
        #: the task-state entries written at every reset and step, in order
        self.task_state_keys = _check_state_keys(
            record.state_keys if task_state_keys is None else task_state_keys, record
        )
        #: whether some env of the last step was broken (a host fact; ZeroBrokenStepReward skips its work without)
        self.last_step_broken = False
        self._record = record
        self._config = config

        facts = ModelFacts.make(env_id, gym_kwargs) if _checked is None else _checked[1]
        self.model: mujoco.MjModel = facts.model
        self.frame_skip = facts.frame_skip
        self.dt = facts.dt
        self.init_qpos = facts.init_qpos.copy()
        self.init_qvel = facts.init_qvel.copy()
        self.state_layout = record.state_layout(facts, self.task_state_keys)
        self.reset_noise_scale = float(config["reset_noise_scale"])
        self._closed = False
        self._setup_batch()
        if self._observation_size != facts.observation_size:  # a Gymnasium version that observes differently
            raise RuntimeError(
                f"{env_id}: the batched observation has {self._observation_size} entries but Gymnasium's has "
                f"{facts.observation_size}; this Gymnasium version is not supported by BatchedMujocoEnv"
            )
        self._make_specs(facts)
        self.np_random: list[np.random.Generator] = []
        self._set_seed(seed)

    # ------------------------------------------------------------------ set-up
    def _setup_batch(self) -> None:
        """Make the batch, bind the arrays the env reads and plan the observation as copies from them.

        ``qpos``, ``qvel``, ``time`` and ``ctrl`` are live views of the batch's state rows; the derived fields
        (``xpos``, ``cinert``, ...) are copied after every call into buffers of the env's own (``_readers``), so that
        a partial reset leaves the others' values and a checkpoint can restore them; ``cfrc_ext`` is computed here.
        """
        record, config, model, n = self._record, self._config, self.model, self.num_envs
        # The contact forces need the contacts of each env's last substep, which only a persistent batch (one MjData
        # per simulation, copied whole by get_data) keeps. Without them one MjData per thread serves all simulations:
        # it stays in cache, and a step between Python work is faster (HalfCheetah x64 with a collector's worth of
        # tensor work between steps: 2.21 against 2.44 ms, medians of 5, 2026-11-27).
        contacts = "cfrc_ext" in self.task_state_keys or any(
            part.source == "cfrc_ext" for part in record.observation_parts(config)
        )
        self.batch = batch = Batch(model, n, self.num_threads, persistent=contacts)
        if batch.nstate != mujoco.mj_stateSize(model, _INTEGRATION_STATE):  # what the checkpoints save as rows
            raise RuntimeError(
                f"BatchedMujocoEnv({self.env_id}): mujoco.batch state rows of {batch.nstate} values are not "
                f"mjSTATE_INTEGRATION ({mujoco.mj_stateSize(model, _INTEGRATION_STATE)}); this MuJoCo is not supported"
            )
        self._qpos, self._qvel, self._clock, self._ctrl = (batch.bind(f) for f in ("qpos", "qvel", "time", "ctrl"))
        # [time, qpos, qvel] lead each mjSTATE_INTEGRATION row: one view checks them all for non-finite values
        self._physics = batch.state[:, : 1 + model.nq + model.nv]
        for part in (self._clock, self._qpos, self._qvel):
            if not np.shares_memory(part, self._physics):
                raise RuntimeError(
                    f"BatchedMujocoEnv({self.env_id}): mujoco.batch state rows do not start with [time, qpos, qvel]; "
                    "this MuJoCo is not supported"
                )
        self._warnings = batch.warning[:, :, _WARNING_NUMBER]
        self._time = np.zeros(n)
        self._half_timestep = 0.5 * float(model.opt.timestep)
        #: the domain fields and the per-env values set so far (model fields expanded only once written)
        self._domain = BatchDomain(model, batch, f"BatchedMujocoEnv({self.env_id})")
        #: each env's model for mj_rnePostConstraint (the shared one until its per-env fields are written); None: all
        #: envs have the shared model
        self._env_models: list[mujoco.MjModel] | None = None
        #: (buffer, source): buffer[ids] = source[ids] after every call on simulations ids (source: a bound output;
        #: None for the contact forces, computed into their buffer)
        self._readers: list[tuple[np.ndarray, np.ndarray | None]] = []
        #: the contact forces, which Batch leaves at 0: mj_rnePostConstraint per env (see _read_outputs)
        self._contact_forces: np.ndarray | None = None
        self._scratch: mujoco.MjData | None = None

        def reader(attribute: str, index: tuple[Any, ...] = ()) -> np.ndarray:
            source = batch.bind(attribute)[(slice(None), *index)]
            buffer = np.zeros(source.shape)
            if attribute == "cfrc_ext":
                self._contact_forces, self._scratch = buffer, mujoco.MjData(model)
            self._readers.append((buffer, None if attribute == "cfrc_ext" else source))
            return buffer

        # one array per MjData field that the task state or the observation reads
        arrays = {"qpos": self._qpos, "qvel": self._qvel}

        def array(attribute: str) -> np.ndarray:
            if attribute not in arrays:
                arrays[attribute] = reader(attribute)
            return arrays[attribute]

        def flat(values: np.ndarray, base: np.ndarray) -> np.ndarray:
            # a copy would freeze the plan at set-up: every source must stay a view of what the calls write
            flat_values = values.reshape(n, -1)
            if not np.shares_memory(flat_values, base):
                raise RuntimeError(f"BatchedMujocoEnv({self.env_id}): a planned read is not a view of its array")
            return flat_values

        # the task-state entries, as views of the bound arrays or buffers (the velocities are computed)
        self._entry_sources: dict[str, np.ndarray | None] = {
            key: None if key in record.velocity_keys else flat(array(key), array(key)) for key in self.task_state_keys
        }
        # the forward position that Gymnasium finite-differences into x_velocity (and y_velocity): qpos[0] (Swimmer:
        # qpos[0:2]), the main body's xpos[:2] or the centre of mass (from xipos, weighted by the body masses)
        self._mass_weights: np.ndarray | None = None
        if record.forward_position == "main_body":
            self._position: np.ndarray = reader("xpos", (model.body(config["main_body"]).id, slice(0, 2)))
        elif record.forward_position == "mass_centre":
            self._position = reader("xipos")
            self._mass_weights = np.asarray(model.body_mass, dtype=np.float64)
        else:
            self._position = arrays["qpos"][:, : len(record.velocity_keys)]
        self._previous_position = np.zeros_like(self._forward_position())

        #: (columns, source view, clip bounds or None): the observation is their concatenation
        self._observation_plan: list[tuple[slice, np.ndarray, tuple[float, float] | None]] = []
        start = 0
        for part in record.observation_parts(config):
            source = flat(array(part.source)[:, part.start :], array(part.source))
            self._observation_plan.append((slice(start, start + source.shape[1]), source, part.clip))
            start += source.shape[1]
        self._observation_size = start

    def _make_specs(self, facts: ModelFacts) -> None:
        n, device = self.num_envs, self.device
        batch = torch.Size([n])
        entries = {"observation": Unbounded(shape=(n, self._observation_size), dtype=torch.float64, device=device)}
        for key, size in self.state_layout.items():
            entries[key] = Unbounded(shape=(n, size), dtype=torch.float64, device=device)
        entries[BROKEN_KEY] = Categorical(2, shape=(n, 1), dtype=torch.bool, device=device)
        self.observation_spec = Composite(entries, shape=batch, device=device)
        # Gymnasium's action space: the actuators' ctrlrange as float32
        low = torch.as_tensor(facts.action_low.astype(np.float32)).expand(n, -1)
        high = torch.as_tensor(facts.action_high.astype(np.float32)).expand(n, -1)
        self.action_spec = Bounded(low=low, high=high, shape=low.shape, dtype=torch.float32, device=device)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float64, device=device)
        self.done_spec = Composite(
            {
                key: Categorical(2, shape=(n, 1), dtype=torch.bool, device=device)
                for key in ("done", "terminated", "truncated")
            },
            shape=batch,
            device=device,
        )
        self._action_shape = torch.Size([n, self.model.nu])

    # ------------------------------------------------------------------ simulation
    def _read_outputs(self, ids: np.ndarray | None, post_constraint: bool) -> None:
        """Copy the derived fields of simulations ``ids`` (None: all) out of the batch into the env's buffers.

        With ``post_constraint`` the contact forces are ``mj_rnePostConstraint``'s (what Gymnasium computes after
        a step), else those ``mj_forward`` left (what Gymnasium's reset observes).
        """
        for buffer, source in self._readers:
            if source is None:
                continue
            if ids is None:
                np.copyto(buffer, source)
            else:
                buffer[ids] = source[ids]
        forces = self._contact_forces
        if forces is None:
            return
        # The one Python loop over envs in a step (Ant, Humanoid): Batch has no batched mj_rnePostConstraint and
        # leaves cfrc_ext at 0, and the contact forces need the contacts and constraint forces of each env's last
        # substep, which only its whole MjData holds. get_data copies it (persistent batch) and the forces are
        # computed on the copy: ~10 us per env on an idle machine (Ant/Humanoid x6, 2026-11-27); at x64 on a loaded
        # 2-core machine 2.1 ms of a 17 ms Ant step (2.2 of 22 ms Humanoid), about 12%.
        # With per-env physics each env's forces are computed with its own model (self._env_models). Of the fields
        # offered today cfrc_ext reads none (contacts and constraint forces are MjData's; gravity only enters cacc
        # and cfrc_int), but the call is given the model the simulation ran on, whatever a field kind may add.
        model, models, batch, scratch = self.model, self._env_models, self.batch, self._scratch
        for i in range(self.num_envs) if ids is None else ids.tolist():
            batch.get_data(i, scratch)
            if post_constraint:
                mujoco.mj_rnePostConstraint(model if models is None else models[i], scratch)
            forces[i] = scratch.cfrc_ext

    def _restart(self, ids: np.ndarray) -> None:
        """Put envs ``ids``, whose state is not finite, back to ``qpos0`` as MuJoCo does with a diverged state."""
        self.batch.reset(ids)  # mj_resetData and mj_forward
        self._read_outputs(ids, post_constraint=True)

    # ------------------------------------------------------------------ outputs
    def _outputs(self, velocity: np.ndarray | None, broken: np.ndarray | None, reward: bool) -> TensorDictBase:
        """Fresh tensors on ``self.device``: the observation, the task-state entries, the flags (and a zero reward).

        ``velocity`` (``[num_envs, len(velocity_keys)]``, or None after a reset: zeros) holds the velocities.

        ``broken`` (the envs of a broken step, or None) is written as ``"broken"``, ``"terminated"`` and ``"done"``.
        """
        n = self.num_envs
        observation = np.empty((n, self._observation_size))
        for columns, source, bounds in self._observation_plan:
            if bounds is None:
                observation[:, columns] = source
            else:
                np.clip(source, bounds[0], bounds[1], out=observation[:, columns])
        # the device is read at every call: env.to(device) moves the outputs of the next step
        device = self.device
        if device is None or device.type == "cpu":
            to_torch = torch.from_numpy
        else:

            def to_torch(array: np.ndarray) -> torch.Tensor:
                return torch.from_numpy(array).to(device, non_blocking=True)

        out: dict[str, torch.Tensor] = {"observation": to_torch(observation)}
        velocity_keys = self._record.velocity_keys
        for key in self.state_layout:
            if key in velocity_keys:
                column = velocity_keys.index(key)
                value = np.zeros((n, 1)) if velocity is None else velocity[:, column : column + 1]
            else:
                value = self._entry_sources[key].copy()
            out[key] = to_torch(value)
        flags = np.zeros((n, 1), dtype=bool) if broken is None else broken.reshape(n, 1)
        out[BROKEN_KEY] = to_torch(flags)
        out["terminated"] = to_torch(flags.copy())
        out["done"] = to_torch(flags.copy())
        out["truncated"] = to_torch(np.zeros((n, 1), dtype=bool))
        if reward:
            out["reward"] = to_torch(np.zeros((n, 1)))
        return TensorDict._new_unsafe(out, batch_size=self.batch_size, device=device)

    def _forward_position(self) -> np.ndarray:
        """What Gymnasium finite-differences: ``qpos[:1]`` (Swimmer ``[:2]``), Ant's ``xpos[:2]``, the mass centre."""
        if self._mass_weights is None:
            return self._position.copy()
        weights = self._mass_weights
        if weights.ndim == 2:  # per-env masses (set_domain)
            return (np.einsum("nb,nbj->nj", weights, self._position) / weights.sum(axis=1, keepdims=True))[:, :2]
        return (np.einsum("b,nbj->nj", weights, self._position) / weights.sum())[:, :2]

    def _check_action(self, action: object) -> np.ndarray:
        if not isinstance(action, torch.Tensor):
            raise TypeError(f"action must be a torch.Tensor, got {type(action).__name__}")
        if action.dtype not in (torch.float32, torch.float64):
            raise TypeError(f"action must be a float32 or float64 tensor, got dtype {action.dtype}")
        if action.shape != self._action_shape:
            raise ValueError(
                f"action must have shape {tuple(self._action_shape)} ([num_envs, nu]), got {tuple(action.shape)}"
            )
        # float32 or float64: np.copyto into the float64 controls casts it as .to(torch.float64) would
        return action.detach().cpu().numpy()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(
                f"{self!r} is closed, so it can no longer step or reset. Build a new "
                "env (or deep-copy this one before closing it)."
            )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._check_open()
        ctrl = self._check_action(tensordict.get("action", None))
        skipped = None if np.isfinite(ctrl).all() else ~np.isfinite(ctrl).all(axis=1)
        stepped = None if skipped is None else np.flatnonzero(~skipped)
        if stepped is None:
            np.copyto(self._ctrl, ctrl)
        else:  # a skipped env keeps its controls, as it keeps its state
            self._ctrl[stepped] = ctrl[stepped]
        self.batch.step(stepped, self.frame_skip)
        self._read_outputs(stepped, post_constraint=True)
        restarted = None
        if not np.isfinite(self._physics).all():  # not caught by MuJoCo's own checks: restart it as MuJoCo would
            restarted = ~np.isfinite(self._physics).all(axis=1)
            self._restart(np.flatnonzero(restarted))
        # MuJoCo resets a diverged state to qpos0 and time 0 by itself: the clock runs back. The first
        # substep after one of our resets (time 0) cannot show it, so read its warnings there.
        previous_time = self._time
        broken = self._clock < previous_time + self._half_timestep
        broken |= (previous_time == 0.0) & self._warnings[:, _DIVERGENCE_WARNINGS].any(axis=1)
        np.copyto(previous_time, self._clock)  # the arrays are updated in place: no nn.Module attribute set per step
        if restarted is not None:
            broken |= restarted
        if skipped is not None:
            broken |= skipped
        position = self._forward_position()
        velocity = (position - self._previous_position) / self.dt
        np.copyto(self._previous_position, position)
        any_broken = bool(broken.any())
        self.__dict__["last_step_broken"] = any_broken
        if not any_broken:
            return self._outputs(velocity, None, reward=True)
        invalid = [] if skipped is None else np.flatnonzero(skipped).tolist()
        diverged = np.flatnonzero(broken if skipped is None else broken & ~skipped).tolist()
        warnings.warn(
            f"BatchedMujocoEnv({self.env_id}): episodes ended by a broken step (terminated=True, broken=True, "
            f"reward 0): non-finite action in envs {invalid}, diverged state in envs {diverged}",
            RuntimeWarning,
            stacklevel=2,
        )
        velocity[broken] = 0.0  # no finite difference across a skipped step or MuJoCo's reset
        return self._outputs(velocity, broken, reward=True)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        """Gymnasium v5's ``reset`` of the masked envs (all without a mask): ``mj_resetData``, noise, ``mj_forward``."""
        self._check_open()
        reset = None if tensordict is None else tensordict.get("_reset", None)
        ids = None if reset is None else np.flatnonzero(reset.reshape(self.num_envs).cpu().numpy())
        if ids is not None and ids.size == self.num_envs:
            ids = None
        if ids is None or ids.size:
            rows = slice(None) if ids is None else ids
            model, scale = self.model, self.reset_noise_scale
            generators = self.np_random if ids is None else [self.np_random[i] for i in ids.tolist()]
            # the other Python loop over envs: each reset env draws from its own generator, qpos then qvel noise
            normal = self._record.velocity_noise == "normal"
            noise = [
                (
                    rng.uniform(low=-scale, high=scale, size=model.nq),
                    scale * rng.standard_normal(model.nv)
                    if normal
                    else rng.uniform(low=-scale, high=scale, size=model.nv),
                )
                for rng in generators
            ]
            self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE)  # mj_resetData
            self._qpos[rows] = self.init_qpos + np.array([qpos for qpos, _ in noise])
            self._qvel[rows] = self.init_qvel + np.array([qvel for _, qvel in noise])
            self.batch.forward(ids)
            self._read_outputs(ids, post_constraint=False)
            self._time[rows] = self._clock[rows]
            self._previous_position[rows] = self._forward_position()[rows]
        return self._outputs(None, None, reward=False)

    def _set_seed(self, seed: int | None) -> None:
        children = np.random.SeedSequence(None if seed is None else int(seed)).spawn(self.num_envs)
        self.np_random = [np.random.Generator(np.random.PCG64(child)) for child in children]

    # ------------------------------------------------------------------ per-env physics
    def domain_fields(self, names: Sequence[str] | None = None) -> list[DomainField]:
        """The physics values this env can give each of its envs, with their nominal values and allowed ranges.

        Args:
            names: the fields to describe, in order; ``None``: every field of the env (``"body_mass:<body>"``,
                ``"body_mass_scale"``, ``"geom_friction:<geom>"``, ..., ``"gravity"``; the kinds are
                :data:`~torchtasks.envs.mujoco_domain.FIELD_KINDS`).

        Raises ``ValueError`` for an unknown name (naming the close ones), a name given twice, and a scale named
        with one object's value of the same kind (``"body_mass_scale"`` with ``"body_mass:torso"``).

        Example:
            >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=2)
            >>> torso, friction = env.domain_fields(["body_mass:torso", "geom_friction_scale"])
            >>> torso.rule, torso.set_const, friction.nominal.item(), friction.rule, friction.set_const
            ('in (0.0, inf)', True, 1.0, 'in [0.0, inf)', False)
            >>> env.close()
        """
        return self._domain.fields(names)

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give the envs of ``mask`` the physics ``values[name][i]``, from their next step or reset on.

        The values persist until set again (resets keep them) and checkpoints keep them. Only the model fields of
        the kinds written become per-env (``Batch.expand``), and ``Batch.set_const`` runs once over the envs written
        if some field written needs it (masses, armatures, gears). A running episode continues from its state.

        Args:
            values: by field name (:meth:`domain_fields`), a float64 tensor ``[num_envs, *value_shape]`` on any
                device; the rows of envs outside ``mask`` are ignored. The rows of the envs written must be finite
                and in the field's range (``ValueError`` naming the field, the env and the value).
            mask: bool ``[num_envs]``, the envs to write; ``None``: all.

        Example:
            >>> import torch
            >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=3, seed=0)
            >>> torso = env.domain_fields(["body_mass:torso"])[0].nominal
            >>> masses = torch.tensor([0.0, 5.0, 6.0], dtype=torch.float64)  # env 0 is not written: its 0 is ignored
            >>> env.set_domain({"body_mass:torso": masses}, mask=torch.tensor([False, True, True]))
            >>> now = env.domain_values(["body_mass:torso"])["body_mass:torso"]
            >>> bool(now[0] == torso), now[1:].tolist()
            (True, [5.0, 6.0])
            >>> env.close()
        """
        rows, ids = self._domain.checked(values, mask, "values")
        if rows and (ids is None or ids.size):
            self._follow_domain(self._domain.write(rows, ids), ids)

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's current value of each field named (``None``: all), as float64 ``[num_envs, *value_shape]``.

        A field never set holds its nominal value. An object's model value is its value times its kind's scale.

        Example:
            >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=2)
            >>> env.domain_values(["gravity"])["gravity"]
            tensor([[ 0.0000,  0.0000, -9.8100],
                    [ 0.0000,  0.0000, -9.8100]], dtype=torch.float64)
            >>> env.close()
        """
        device = self.device
        return {name: torch.from_numpy(value).to(device) for name, value in self._domain.read(names).items()}

    def _follow_domain(self, kinds: set[FieldKind], ids: np.ndarray | None) -> None:
        """Update what the env keeps of the model beside the batch, for the envs ``ids`` whose ``kinds`` were written.

        Ant and Humanoid: each env's model, for its contact forces (:meth:`_read_outputs`). Humanoid: the body masses
        that weigh the mass centre, and the position the next step's velocity is differenced from (with the new
        masses, as Gymnasium's step reads ``body_mass`` before and after the step).
        """
        if not kinds:
            return
        if self._contact_forces is not None:
            # A model per env written (~0.5 MB each for Ant and Humanoid, mostly texture data; the persistent batch
            # already keeps an MjData of ~14 MB of arena per env), refreshed here: ~20 us per env (get_model), not
            # per step. One scratch model refreshed per env and step would cost that at every step.
            models = self._env_models
            if models is None:
                models = self._env_models = [self.model] * self.num_envs
            for i in range(self.num_envs) if ids is None else ids.tolist():
                models[i] = self.batch.get_model(i, None if models[i] is self.model else models[i])
        if self._mass_weights is not None and any(kind.model_field == "body_mass" for kind in kinds):
            self._mass_weights = np.array(self.batch.expanded("body_mass"))
            rows = slice(None) if ids is None else ids
            self._previous_position[rows] = self._forward_position()[rows]

    # ------------------------------------------------------------------ checkpoints
    def get_extra_state(self) -> dict[str, Any]:
        """The reset generators and the running episodes (see the class's "Checkpoints").

        ``{"bit_generators": [numpy bit_generator.state of each env], "running_episodes": {...}}``.
        """
        return {
            "bit_generators": [copy.deepcopy(rng.bit_generator.state) for rng in self.np_random],
            "running_episodes": self._running_episodes(),
        }

    def set_extra_state(self, state: Any) -> None:
        """Restore what :meth:`get_extra_state` saved (checked whole before anything is written)."""
        saved = state.get("bit_generators") if isinstance(state, Mapping) else None
        if not isinstance(saved, Sequence) or len(saved) != self.num_envs:
            raise ValueError(
                f"BatchedMujocoEnv.load_state_dict: the extra state must hold 'bit_generators', one numpy "
                f"bit_generator.state per env ({self.num_envs}), got {state!r}"
            )
        generators = []
        for i, bit_state in enumerate(saved):
            name = bit_state.get("bit_generator") if isinstance(bit_state, Mapping) else None
            kind = getattr(np.random, name, None) if isinstance(name, str) else None
            if not (isinstance(kind, type) and issubclass(kind, np.random.BitGenerator)):
                raise ValueError(
                    f"BatchedMujocoEnv.load_state_dict: bit_generators[{i}] is not a numpy bit_generator.state "
                    f"(a dict naming a numpy BitGenerator), got {bit_state!r}"
                )
            bit_generator = kind()
            bit_generator.state = bit_state
            generators.append(np.random.Generator(bit_generator))
        running = state.get("running_episodes")  # absent from checkpoints written before it was saved
        if running is not None:
            running = self._checked_running_episodes(running, "BatchedMujocoEnv.load_state_dict")
        self.np_random = generators
        if running is not None:
            self._load_running_episodes(running)

    def _model_facts(self) -> dict[str, Any]:
        """What a saved simulation state belongs to: the env, its batch, its substeps and its compiled model."""
        binary = np.empty(mujoco.mj_sizeModel(self.model), dtype=np.uint8)
        mujoco.mj_saveModel(self.model, None, binary)
        return {
            "env_id": self.env_id,
            "num_envs": self.num_envs,
            "frame_skip": self.frame_skip,
            "model_sha256": hashlib.sha256(binary.tobytes()).hexdigest(),
        }

    def _running_episodes(self) -> dict[str, Any]:
        """Everything the next step or partial reset reads besides its input, as tensors (copies)."""
        # the batch's state rows are mj_getState(mjSTATE_INTEGRATION) of each simulation
        physics = np.concatenate([self._clock[:, None], self._qpos, self._qvel], axis=1)  # [time, qpos, qvel]
        gathered = [physics, *(buffer for buffer, _ in self._readers)]
        return {
            "model": self._model_facts(),
            "integration_state": torch.from_numpy(self.batch.state.copy()),
            "warnings": torch.from_numpy(self._warnings.astype(np.int64)),
            "time": torch.from_numpy(self._time.copy()),
            "previous_position": torch.from_numpy(np.array(self._previous_position)),
            "gathered": [torch.from_numpy(array.copy()) for array in gathered],
            _DOMAIN_KEY: self._domain.saved(),
        }

    def _checked_running_episodes(self, running: Any, owner: str) -> dict[str, Any]:
        """``running`` as :meth:`_running_episodes` wrote it for this env; else a ``ValueError`` naming both sides."""
        if not isinstance(running, Mapping) or set(running) - {_DOMAIN_KEY} != set(_RUNNING_KEYS):
            got = sorted(running) if isinstance(running, Mapping) else type(running).__name__
            raise ValueError(
                f"{owner}: 'running_episodes' must be a dict of {list(_RUNNING_KEYS)} (and {_DOMAIN_KEY!r}), got {got}"
            )
        mine = self._running_episodes()
        saved_model, own_model = dict(running["model"]), mine["model"]
        if saved_model != own_model:
            differ = sorted(
                key for key in own_model.keys() | saved_model.keys() if saved_model.get(key) != own_model.get(key)
            )
            raise ValueError(
                f"{owner}: the saved running episodes are of another simulation ({', '.join(differ)} differ): "
                f"saved {saved_model}, this env {own_model}"
            )
        if not isinstance(running["gathered"], Sequence) or len(running["gathered"]) != len(mine["gathered"]):
            raise ValueError(
                f"{owner}: 'gathered' must be a list of {len(mine['gathered'])} tensors for this env, "
                f"got {running['gathered']!r}"
            )
        names = ["integration_state", "warnings", "time", "previous_position"]
        pairs = [(name, running[name], mine[name]) for name in names]
        pairs += [
            (f"gathered[{i}]", a, b) for i, (a, b) in enumerate(zip(running["gathered"], mine["gathered"], strict=True))
        ]
        for name, value, own in pairs:
            if not isinstance(value, torch.Tensor) or value.shape != own.shape or value.dtype != own.dtype:
                got = f"{value.dtype} {list(value.shape)}" if isinstance(value, torch.Tensor) else repr(value)
                raise ValueError(
                    f"{owner}: the saved '{name}' must be a {own.dtype} tensor of shape {list(own.shape)} for this "
                    f"env, got {got}"
                )
        # the per-env physics: known fields of this env's shapes and ranges (a scale and one object's value may both
        # have been set, by two set_domain calls)
        self._domain.checked(running.get(_DOMAIN_KEY, {}), None, f"the saved {_DOMAIN_KEY!r} ({owner})", overlap=True)
        return dict(running)

    def _load_running_episodes(self, running: Mapping[str, Any]) -> None:
        """Put the (checked) running episodes of :meth:`_running_episodes` into the ``MjData`` and the buffers."""
        # the physics first (a field set here but not saved goes back to nominal; checkpoints written before the
        # domain was saved hold none); set_const leaves the state rows alone
        domain = {name: value.cpu().numpy() for name, value in running.get(_DOMAIN_KEY, {}).items()}
        self._follow_domain(self._domain.load(domain), None)
        # the state rows carry time, qpos and qvel: gathered[0] ([time, qpos, qvel]) holds the same values
        self.batch.state[:] = running["integration_state"].cpu().numpy()
        self._warnings[:] = running["warnings"].cpu().numpy()
        self._time = running["time"].cpu().numpy().copy()
        self._previous_position = running["previous_position"].cpu().numpy().copy()
        for (array, _), values in zip(self._readers, running["gathered"][1:], strict=True):
            array[:] = values.cpu().numpy()

    # ------------------------------------------------------------------ copies and pickles
    def __getstate__(self) -> dict[str, Any]:
        """The env's state without its batch, with the simulations and buffers as in the running episodes."""
        state = dict(super().__getstate__())
        for key in _REBUILT:
            state.pop(key, None)
        if self.__dict__.get("batch") is not None:
            state["_saved_running_episodes"] = self._running_episodes()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        running = state.pop("_saved_running_episodes", None)
        super().__setstate__(state)
        if running is None:  # pickled before __init__ had built the simulation
            return
        self._setup_batch()
        self._load_running_episodes(running)

    # ------------------------------------------------------------------ lifetime
    def close(self, *, raise_if_closed: bool = True) -> None:
        """Mark the env closed: stepping or resetting afterwards raises a ``RuntimeError``. Closing twice is allowed.

        The batch (its threads and states) stays readable, so that a closed env can still be copied or saved; it
        is released with the env.
        """
        self.__dict__["_closed"] = True
        super().close(raise_if_closed=raise_if_closed)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(env_id={self.env_id!r}, num_envs={self.num_envs}, "
            f"num_threads={self.num_threads}, frame_skip={self.frame_skip}, device={self.device})"
        )


class ZeroBrokenStepReward(Transform):
    """Pay 0 for a broken step of a :class:`BatchedMujocoEnv`: in the reward and every other reward entry.

    A task reads the policy's action: a non-finite action (which the env does not simulate and
    ends the episode on, marking it ``("next", "broken")``) gives a non-finite control cost and so
    a non-finite reward, which a following ``RewardSum`` would carry into ``"episode_reward"`` and
    a training batch. Put this transform after the task's ``TaskTransform`` and before
    ``RewardSum``: where ``("next", broken_key)`` is True it writes 0 into every entry of the
    reward spec (``"reward"`` and the task's named terms); elsewhere nothing changes.
    :func:`~torchtasks.envs.locomotion.gymnasium_env` puts it there for the batched backend.

    Args:
        broken_key: the entry marking broken steps (``[*B, 1]`` bool).

    Example:
        >>> import torch, warnings
        >>> from torchtasks.envs.locomotion import gymnasium_env
        >>> env = gymnasium_env("Swimmer-v5", num_envs=2, seed=0)
        >>> action = torch.zeros(2, 2); action[1, 0] = float("nan")
        >>> with warnings.catch_warnings():
        ...     warnings.simplefilter("ignore", RuntimeWarning)
        ...     out = env.step(env.reset().set("action", action))["next"]
        >>> out["broken"][:, 0], out["terminated"][:, 0], out["reward"][1, 0].item()
        (tensor([False,  True]), tensor([False,  True]), 0.0)
        >>> bool(out["episode_reward"].isfinite().all())
        True
        >>> env.close()
    """

    def __init__(self, broken_key: str = BROKEN_KEY) -> None:
        if not isinstance(broken_key, str):
            raise TypeError(f"broken_key must be a string, got {broken_key!r}")
        super().__init__(in_keys=[], out_keys=[])
        self.broken_key = broken_key
        self._reward_keys: list[Any] | None = None

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        if self.broken_key not in observation_spec.keys():
            raise KeyError(
                f"ZeroBrokenStepReward: the env has no {self.broken_key!r} entry (a BatchedMujocoEnv writes one); "
                f"its observation keys are {sorted(map(str, observation_spec.keys()))}"
            )
        return observation_spec

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        self._reward_keys = list(reward_spec.keys(True, True))
        return reward_spec

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        container = container_env(self)
        if getattr(getattr(container, "base_env", None), "last_step_broken", True) is False:
            # a host fact of a BatchedMujocoEnv below: no broken env in this step, no tensor to read
            return next_tensordict
        broken = next_tensordict.get(self.broken_key, None)
        if broken is None:
            return next_tensordict
        keys = self._reward_keys
        if keys is None:  # the specs were not built yet: the reward entries of the env before this transform
            keys = self._reward_keys = list(self.parent.full_reward_spec.keys(True, True))
        for key in keys:
            value = next_tensordict.get(key, None)
            if value is None:
                continue
            mask = broken.reshape(*broken.shape[:-1], *([1] * (value.ndim - broken.ndim + 1)))
            next_tensordict.set(key, torch.where(mask, torch.zeros((), dtype=value.dtype, device=value.device), value))
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset
