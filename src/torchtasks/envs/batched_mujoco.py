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
import weakref
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, Transform

from torchtasks._checks import check_non_negative_int, check_positive_int
from torchtasks._did_you_mean import did_you_mean
from torchtasks._optional import missing_extra
from torchtasks._torchrl import container_env

try:
    import mujoco
    from mujoco.batch import _STATE_FIELDS, Batch
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.batched_mujoco (BatchedMujocoEnv)", _error) from _error

from torchtasks.domain.fields import DomainField
from torchtasks.envs.action_delay import ACTION_DELAY, APPLIED_ACTION_KEY, SAVED_KEYS, ActionQueue, action_delay_field
from torchtasks.envs.body_pushes import PushableBodies
from torchtasks.envs.gymnasium_v5 import (
    LOCOMOTION_ENVS,
    LocomotionEnvRecord,
    ModelFacts,
    gymnasium_config,
    gymnasium_declaration,
    locomotion_record,
)
from torchtasks.envs.mujoco_declaration import Actions, FreeJointRanges, Resets, declare
from torchtasks.envs.mujoco_domain import BatchDomain, FieldKind
from torchtasks.envs.readings import Resolved
from torchtasks.envs.reset_steps import ResetContext

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
#: entries of the running episodes that checkpoints written before the env had them lack: the last actions, the
#: states queued for the next resets (set_reset_states; NaN rows: none)
_OPTIONAL_RUNNING_KEYS = ("last_action", "queued_qpos", "queued_qvel")
#: the entry of the per-env physics (the values of every domain field ever set), absent from checkpoints written
#: before the env had one (they load as nominal physics)
_DOMAIN_KEY = "domain"
#: attributes rebuilt when a copy or a pickle is restored: the batch (its C threads and state rows, restored from
#: the integration states on the one MjModel) and the bound arrays, buffers and observation plan (numpy views of
#: the batch and of each other, which a copy would turn into independent arrays)
_REBUILT = (
    "batch",
    "_context",
    "_qpos",
    "_qvel",
    "_clock",
    "_ctrl",
    "_xfrc_applied",
    "_physics",
    "_warnings",
    "_readers",
    "_contact_forces",
    "_scratch",
    "_domain",
    "_env_models",
    "_arrays",
    "_model_fields",
    "_last_action",
    "_affine",
    "_differences",
    "_previous",
    "_sizes",
    "_plan",
    "_queued_qpos",
    "_queued_qvel",
    "_time",
    "_half_timestep",
    "_stage",
    "_delay",
)


#: every batch of this process's envs, and, in a child forked from it, the parent's batches kept alive: a batch's
#: worker threads are not copied by fork, and destroying an inherited batch (when the child's garbage collector frees
#: a copy of the parent's env, e.g. the env a ParallelEnv built for its specs) waits for those threads forever
_LIVE_BATCHES: weakref.WeakSet[Batch] = weakref.WeakSet()
_INHERITED_BATCHES: list[Batch] = []


def _keep_inherited_batches() -> None:
    _INHERITED_BATCHES.extend(_LIVE_BATCHES)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_keep_inherited_batches)


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


def _flat(array: np.ndarray, n: int) -> np.ndarray:
    return array.reshape(n, -1)


def _looks_like_id(text: str) -> bool:
    """Whether ``text`` reads as a Gymnasium id (``Name-v5``) rather than a file or MJCF."""
    return not text.lstrip().startswith("<") and "-v" in text and not os.path.exists(text) and "." not in text


def _fields(part: Resolved) -> tuple[str, ...]:
    """The MjData fields a reading reads, its finite difference's inner reading's included."""
    return part.fields + (() if part.difference_of is None else _fields(part.difference_of))


def _model_fields(part: Resolved) -> tuple[str, ...]:
    """The per-env model fields a reading reads, its finite difference's inner reading's included."""
    return part.model_fields + (() if part.difference_of is None else _model_fields(part.difference_of))


def _reads(part: Resolved, field: str) -> bool:
    return field in _fields(part)


def _free_joint_draw(rng: np.random.Generator, ranges: FreeJointRanges) -> np.ndarray:
    """A free joint's draws: position offsets (3), yaw (1), linear and angular velocity offsets (3 each)."""
    out = np.zeros(10)
    for columns, pairs in (
        (slice(0, 3), ranges.position),
        (slice(3, 4), None if ranges.yaw is None else (ranges.yaw,)),
        (slice(4, 7), ranges.linear_velocity),
        (slice(7, 10), ranges.angular_velocity),
    ):
        if pairs is not None:
            low, high = np.array(pairs, dtype=np.float64).T
            out[columns] = rng.uniform(low, high)
    return out


def _quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton products ``a * b`` of ``[k, 4]`` quaternions (w, x, y, z), as ``mju_mulQuat``."""
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=1,
    )


class BatchedMujocoEnv(EnvBase):
    """Step ``num_envs`` simulations of any MuJoCo model in one process, one ``mujoco.batch`` call per step.

    ``model`` is a ``mujoco.MjModel``, an ``mujoco.MjSpec``, an MJCF file or string, or a Gymnasium MuJoCo v5
    locomotion id (``"Hopper-v5"``: the Gymnasium preset, a declaration of this env equal to Gymnasium bit for
    bit, with ``**gym_kwargs``). A step writes ``ctrl = offset + scale * action`` (:class:`Actions`), advances every
    env ``frame_skip`` substeps in one ``Batch.step`` call on ``num_threads`` threads, and computes every declared
    entry for all envs at once from the bound ``(num_envs, ...)`` arrays: ``observation`` (one ``"observation"``
    vector, or a dict of entries) and ``state`` (the task-state entries a task reads), each a list of
    :mod:`~torchtasks.envs.readings`. It pays no reward and ends no episode (put a task's
    :class:`~torchtasks.transforms.TaskTransform` on it), except a broken step (a non-finite action, a diverged
    state): that env ends, with ``"broken"`` set, a finite state and a ``RuntimeWarning``
    (:class:`ZeroBrokenStepReward` pays 0 for it). Resets draw from one generator per env (:class:`Resets`), for
    the masked envs only; ``"reset_qpos"``/``"reset_qvel"`` (float64 ``[num_envs, nq|nv]``) in the reset
    tensordict start the masked envs from those states instead (:meth:`set_reset_states` queues them for the next
    reset wherever TorchRL resets). ``state_dict()`` holds the generators and the running episodes (a load
    continues them bit for bit; :class:`~torchtasks.transforms.BaseEnvState` saves them in a ``TransformedEnv``);
    copies and pickles are independent envs in the same state. As a :class:`~torchtasks.domain.DomainEnv` it gives
    each env its own physics (:meth:`set_domain`). Docs: "Your own robot", "The batched MuJoCo env".

    Args:
        model: the model, or a Gymnasium id (then ``observation`` ... ``stage`` are the preset's).
        num_envs: number of simulations.
        observation: a reading, a list of readings (one ``"observation"`` entry) or ``{key: readings}``.
        state: ``{key: readings}``: the task-state entries (float64 ``[num_envs, size]`` each).
        actions: :class:`Actions` (default: the action is the control).
        resets: :class:`Resets` (default: ``qpos0`` and zero velocities).
        frame_skip, control_timestep: substeps per step, or the step in seconds (default: one substep).
        stage: ``"velocity"`` (readings of the returned state, as dm_control) or ``"step"`` (as ``mj_step`` leaves
            ``MjData``: derived fields of the last substep, as Gymnasium).
        seed: seed of the per-env generators (``set_seed`` reseeds them); ``None``: fresh entropy.
        device: device of the output tensors (the simulation runs on the CPU).
        num_threads: threads that step the envs; default: the CPUs this process may use, at most ``num_envs``.
        max_action_delay: the largest per-env action delay, in steps (:mod:`~torchtasks.envs.action_delay`); 0: none.
        task_state_keys: a Gymnasium id's task-state entries.
        **gym_kwargs: a Gymnasium id's keyword arguments.

    Example:
        >>> from torchtasks.envs import BatchedMujocoEnv, readings
        >>> xml = '''<mujoco><worldbody><body name="pole"><joint name="hinge"/>
        ...   <geom type="capsule" fromto="0 0 0 0 0 1" size="0.05"/></body></worldbody>
        ...   <actuator><motor joint="hinge" ctrlrange="-1 1"/></actuator></mujoco>'''
        >>> env = BatchedMujocoEnv(xml, 4, observation={"angle": readings.joint_pos("hinge")},
        ...                        state={"tip_height": readings.body_pos("pole")}, frame_skip=5, seed=0)
        >>> rollout = env.rollout(3)
        >>> rollout["next", "angle"].shape, rollout["next", "tip_height"].dtype
        (torch.Size([4, 3, 1]), torch.float64)
        >>> hopper = BatchedMujocoEnv("Hopper-v5", num_envs=2, seed=0)
        >>> hopper.rollout(3)["next", "observation"].shape
        torch.Size([2, 3, 11])
        >>> for e in (env, hopper): e.close()
    """

    batch_locked = True
    #: ``frame_skip`` is MuJoCo's substeps per step, done in ``_step`` (TorchRL must not add a FrameSkipTransform)
    _has_frame_skip = True

    def __init__(
        self,
        model: Any,
        num_envs: int,
        *,
        observation: Any = None,
        state: Any = None,
        actions: Actions | None = None,
        resets: Resets | None = None,
        frame_skip: int | None = None,
        control_timestep: float | None = None,
        stage: str = "velocity",
        seed: int | None = None,
        device: torch.device | str | None = None,
        num_threads: int | None = None,
        max_action_delay: int = 0,
        task_state_keys: Sequence[str] | None = None,
        _checked: tuple[dict[str, Any], ModelFacts] | None = None,
        **gym_kwargs: Any,
    ) -> None:
        # _checked: the keywords already validated by gymnasium_config and the facts of a Gymnasium env made with
        # them (gymnasium_env passes the ones it read, so that one Gymnasium env is made and the keywords checked once)
        num_envs = check_positive_int(num_envs, "num_envs")
        num_threads = min(
            _default_threads() if num_threads is None else check_positive_int(num_threads, "num_threads"), num_envs
        )
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise TypeError(f"seed must be an int or None, got {seed!r}")
        max_action_delay = check_non_negative_int(max_action_delay, "max_action_delay")
        env_id = model if isinstance(model, str) and model in LOCOMOTION_ENVS else None
        if env_id is not None:
            if frame_skip is not None:  # Gymnasium's keyword of the same name
                gym_kwargs["frame_skip"] = frame_skip
            given = {"observation": observation, "state": state, "actions": actions, "resets": resets}
            given.update(control_timestep=control_timestep, stage=None if stage == "velocity" else stage)
            passed = sorted(name for name, value in given.items() if value is not None)
            if passed:
                raise TypeError(
                    f"{env_id} is a Gymnasium preset declared by torchtasks: it takes Gymnasium's keyword arguments "
                    f"(and task_state_keys), not {passed}; for a declaration of your own pass a model"
                )
            config = gymnasium_config(env_id, gym_kwargs) if _checked is None else _checked[0]
            if config.get("render_mode") is not None:
                raise ValueError(f"BatchedMujocoEnv does not render; got render_mode={config['render_mode']!r}")
            record = locomotion_record(env_id)
            facts = ModelFacts.make(env_id, gym_kwargs) if _checked is None else _checked[1]
            keys = _check_state_keys(record.state_keys if task_state_keys is None else task_state_keys, record)
            declaration = gymnasium_declaration(record, config, facts, keys)
        else:
            if gym_kwargs or task_state_keys is not None or _checked is not None:
                unexpected = sorted(gym_kwargs) + (["task_state_keys"] if task_state_keys is not None else [])
                raise TypeError(
                    f"BatchedMujocoEnv got unexpected keyword argument(s) {unexpected}: they are the keywords of a "
                    f"Gymnasium id (one of {list(LOCOMOTION_ENVS)}); a model of your own takes observation=, "
                    "state=, actions=, resets=, frame_skip= or control_timestep=, stage="
                )
            if isinstance(model, str) and _looks_like_id(model):
                raise ValueError(
                    f"model {model!r} is neither a Gymnasium preset (one of {list(LOCOMOTION_ENVS)}"
                    f"{did_you_mean(model, list(LOCOMOTION_ENVS))}) nor a model file; for your own robot pass an "
                    "MjModel, an MjSpec, an MJCF file or string (docs: 'Your own robot')"
                )
            declaration = declare(
                model,
                observation=observation,
                state=state,
                actions=actions,
                resets=resets,
                frame_skip=frame_skip,
                control_timestep=control_timestep,
                stage=stage,  # type: ignore[arg-type]
            )
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        #: the Gymnasium id of a preset, else None
        self.env_id = env_id
        self.num_envs = num_envs
        self.num_threads = num_threads
        self.gym_kwargs = dict(gym_kwargs) if env_id is not None else {}
        #: the declaration the env runs (model, readings, actions, resets, substeps)
        self.declaration = declaration
        #: the task-state entries written at every reset and step, in order
        self.task_state_keys = tuple(declaration.state)
        #: whether some env of the last step was broken (a host fact; ZeroBrokenStepReward skips its work without)
        self.last_step_broken = False
        self.model: mujoco.MjModel = declaration.model
        self.frame_skip = declaration.frame_skip
        self.dt = declaration.dt
        keyframe = declaration.resets.keyframe
        #: the default state of a reset, before its draws (``qpos0`` and zeros, or the keyframe's)
        self.init_qpos = np.array(self.model.qpos0 if keyframe < 0 else self.model.key_qpos[keyframe])
        self.init_qvel = np.zeros(self.model.nv) if keyframe < 0 else np.array(self.model.key_qvel[keyframe])
        self._closed = False
        #: the bodies pushes reach (add_body_velocity, set_body_wrench)
        self._pushes = PushableBodies(self.model, f"BatchedMujocoEnv({declaration.name})")
        #: the largest action delay (steps) the ``"action_delay"`` domain field may take; 0: no delay, no field
        self.max_action_delay = max_action_delay
        self._setup_batch()
        #: ``{key: size}`` of the task-state entries, in order
        self.state_layout = {key: self._sizes[key] for key in declaration.state}
        if env_id is not None and self._sizes["observation"] != facts.observation_size:
            raise RuntimeError(
                f"{env_id}: the batched observation has {self._sizes['observation']} entries but Gymnasium's has "
                f"{facts.observation_size}; this Gymnasium version is not supported by BatchedMujocoEnv"
            )
        self._make_specs()
        self.np_random: list[np.random.Generator] = []
        self._set_seed(seed)

    # ------------------------------------------------------------------ set-up
    def _setup_batch(self) -> None:
        """Make the batch, bind the arrays the readings read, and size every entry.

        State fields (``qpos``, ``qvel``, ``time``, ``ctrl``, ...) are live views of the batch's state rows; derived
        fields (``xpos``, ``sensordata``, ...) are copied after every call into buffers of the env's own, so that a
        partial reset leaves the others' values and a checkpoint can restore them.
        """
        declaration, model, n = self.declaration, self.model, self.num_envs
        after_step = declaration.contact_forces == "after_step"
        parts = [part for parts in declaration.entries().values() for part in parts]
        # A persistent batch keeps one MjData per simulation. Gymnasium's contact forces need it (the contacts of
        # each env's last substep, copied whole by get_data), and readings of the returned state (stage "velocity")
        # come for free with it: its next step continues from the stages computed after the last (mujoco.batch's
        # docs). Shipped quadruped x64, env in a Collector over the Batch.step floor, interleaved, 2 runs of 3
        # repeats under load ~2: persistent 0.76 and 0.72, one MjData per thread 0.54 and 0.65 (2026-12-02).
        # Without either, one MjData per thread serves all simulations: it stays in cache, and a step between Python
        # work is faster (HalfCheetah x64 with a collector's worth of tensor work between steps: 2.21 against 2.44 ms,
        # medians of 5, 2026-11-27).
        needs_contacts = after_step and any(_reads(part, "cfrc_ext") for part in parts)
        persistent = needs_contacts or declaration.stage == "velocity"
        self.batch = batch = Batch(model, n, self.num_threads, persistent=persistent)
        _LIVE_BATCHES.add(batch)
        if batch.nstate != mujoco.mj_stateSize(model, _INTEGRATION_STATE):  # what the checkpoints save as rows
            raise RuntimeError(
                f"BatchedMujocoEnv({declaration.name}): mujoco.batch state rows of {batch.nstate} values are not "
                f"mjSTATE_INTEGRATION ({mujoco.mj_stateSize(model, _INTEGRATION_STATE)}); this MuJoCo is not supported"
            )
        self._qpos, self._qvel, self._clock, self._ctrl = (batch.bind(f) for f in ("qpos", "qvel", "time", "ctrl"))
        #: the external wrenches of every body (set_body_wrench), a view of the state rows
        self._xfrc_applied = batch.bind("xfrc_applied")
        # [time, qpos, qvel] lead each mjSTATE_INTEGRATION row: one view checks them all for non-finite values
        self._physics = batch.state[:, : 1 + model.nq + model.nv]
        for part in (self._clock, self._qpos, self._qvel):
            if not np.shares_memory(part, self._physics):
                raise RuntimeError(
                    f"BatchedMujocoEnv({declaration.name}): mujoco.batch state rows do not start with [time, qpos, "
                    "qvel]; this MuJoCo is not supported"
                )
        self._warnings = batch.warning[:, :, _WARNING_NUMBER]
        self._time = np.zeros(n)
        self._half_timestep = 0.5 * float(model.opt.timestep)
        self._stage = int(mujoco.mjtStage.mjSTAGE_VEL) if declaration.stage == "velocity" else 0
        #: the domain fields and the per-env values set so far (model fields expanded only once written)
        delay = self.max_action_delay
        self._domain = BatchDomain(
            model, batch, f"BatchedMujocoEnv({declaration.name})", (action_delay_field(delay),) if delay else ()
        )
        #: the delayed actions (max_action_delay > 0), else None: the step applies the policy's action
        self._delay = ActionQueue(n, model.nu, delay) if delay else None
        #: each env's model for mj_rnePostConstraint (the shared one until its per-env fields are written); None: all
        #: envs have the shared model
        self._env_models: list[mujoco.MjModel] | None = None
        #: (buffer, source): buffer[ids] = source[ids] after every call on simulations ids (source: a bound output;
        #: None for Gymnasium's contact forces, computed into their buffer)
        self._readers: list[tuple[np.ndarray, np.ndarray | None]] = []
        self._contact_forces: np.ndarray | None = None
        self._scratch: mujoco.MjData | None = None
        #: the arrays readings compute from: MjData fields by name (state fields live, outputs the env's buffers)
        self._arrays: dict[str, np.ndarray] = {"qpos": self._qpos, "qvel": self._qvel, "time": self._clock}
        state_fields = set(_STATE_FIELDS)
        for name in sorted({name for part in parts for name in _fields(part)}):
            if name in self._arrays:
                continue
            if name in state_fields:
                self._arrays[name] = batch.bind(name)
                continue
            source = batch.bind(name)
            buffer = np.zeros(source.shape)
            if name == "cfrc_ext" and after_step:
                self._contact_forces, self._scratch = buffer, mujoco.MjData(model)
                self._readers.append((buffer, None))
            else:
                self._readers.append((buffer, source))
            self._arrays[name] = buffer
        self._model_fields = sorted({name for part in parts for name in _model_fields(part)})
        #: states queued by set_reset_states for each env's next reset (NaN rows: none; qvel NaN: the default's)
        self._queued_qpos = np.full((n, model.nq), np.nan)
        self._queued_qvel = np.full((n, model.nv), np.nan)
        #: the last action of each env (zeros after a reset), for last_action readings and checkpoints
        self._last_action = np.zeros((n, model.nu))
        self._affine = not ((declaration.action_scale == 1.0).all() and (declaration.action_offset == 0.0).all())
        #: the finite differences: their readings and each one's value at the previous reset or step
        self._differences: list[Resolved] = []
        for part in parts:
            if part.difference_of is not None and part not in self._differences:
                self._differences.append(part)
        self._previous = [np.zeros((n, int(np.prod(part.shape)))) for part in self._differences]
        #: every entry as its parts: (reading, None) or (finite difference, its index in _differences)
        self._plan = [
            (key, [(part, self._differences.index(part) if part.difference_of is not None else None) for part in parts])
            for key, parts in declaration.entries().items()
        ]
        self._sizes = {
            key: sum(int(np.prod(part.shape)) for part in parts) for key, parts in declaration.entries().items()
        }

    def _make_specs(self) -> None:
        n, device, declaration = self.num_envs, self.device, self.declaration
        batch = torch.Size([n])
        entries: dict[str, Any] = {
            key: Unbounded(shape=(n, size), dtype=torch.float64, device=device) for key, size in self._sizes.items()
        }
        entries[BROKEN_KEY] = Categorical(2, shape=(n, 1), dtype=torch.bool, device=device)
        if self._delay is not None:
            entries[APPLIED_ACTION_KEY] = Unbounded(shape=(n, self.model.nu), dtype=torch.float64, device=device)
        self.observation_spec = Composite(entries, shape=batch, device=device)
        nu = self.model.nu
        if declaration.action_low is None:
            self.action_spec = Unbounded(shape=(n, nu), dtype=torch.float32, device=device)
        else:
            low = torch.as_tensor(declaration.action_low.astype(np.float32)).expand(n, -1)
            high = torch.as_tensor(declaration.action_high.astype(np.float32)).expand(n, -1)
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
        self._action_shape = torch.Size([n, nu])

    # ------------------------------------------------------------------ simulation
    def _read_outputs(self, ids: np.ndarray | None, post_constraint: bool) -> None:
        """Copy the derived fields of simulations ``ids`` (None: all) out of the batch into the env's buffers.

        Gymnasium's contact forces (a preset that observes them) are ``mj_rnePostConstraint``'s with
        ``post_constraint`` (what Gymnasium computes after a step), else those ``mj_forward`` left (what
        Gymnasium's reset observes: none).
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
        # The one Python loop over envs in a step, for Gymnasium's Ant and Humanoid only: their contact forces are
        # those of an mj_rnePostConstraint called after mj_step on the whole MjData, which Batch has no batched call
        # for (a model's own force sensors compute them in the last substep's forward pass instead, in the batch,
        # and differ). get_data copies each env's MjData (persistent batch) and the forces are computed on the copy:
        # ~10 us per env on an idle machine (Ant/Humanoid x6, 2026-11-27); at x64 on a loaded 2-core machine 2.1 ms
        # of a 17 ms Ant step (2.2 of 22 ms Humanoid), about 12%.
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

    def _inputs(self) -> dict[str, np.ndarray]:
        """The arrays readings compute from: the bound fields, per-env model fields and the last action."""
        arrays = dict(self._arrays)
        n = self.num_envs
        for name in self._model_fields:
            values = self.batch.expanded(name)
            if values is None:
                shared = np.asarray(
                    getattr(self.model.opt, name[4:]) if name.startswith("opt.") else getattr(self.model, name)
                )
                values = np.broadcast_to(shared, (n, *shared.shape))
            arrays["model." + name] = values
        arrays["action"] = self._last_action
        return arrays

    # ------------------------------------------------------------------ outputs
    def _outputs(
        self,
        differences: list[np.ndarray] | None,
        broken: np.ndarray | None,
        reward: bool,
        arrays: dict[str, np.ndarray] | None = None,
    ) -> TensorDictBase:
        """Fresh tensors on ``self.device``: every entry, the flags (and a zero reward).

        ``differences`` holds each finite difference's value (None after a reset: zeros); ``broken`` (the envs of a
        broken step, or None) is written as ``"broken"``, ``"terminated"`` and ``"done"``.
        """
        n = self.num_envs
        arrays = self._inputs() if arrays is None else arrays
        # the device is read at every call: env.to(device) moves the outputs of the next step
        device = self.device
        if device is None or device.type == "cpu":
            to_torch = torch.from_numpy
        else:

            def to_torch(array: np.ndarray) -> torch.Tensor:
                return torch.from_numpy(array).to(device, non_blocking=True)

        out: dict[str, torch.Tensor] = {}
        for key, parts in self._plan:
            values = []
            for part, difference in parts:
                if difference is None:
                    values.append(_flat(part.compute(arrays), n))
                elif differences is None:
                    values.append(np.zeros_like(self._previous[difference]))
                else:
                    values.append(differences[difference])
            out[key] = to_torch(values[0] if len(values) == 1 else np.concatenate(values, axis=1))
        flags = np.zeros((n, 1), dtype=bool) if broken is None else broken.reshape(n, 1)
        out[BROKEN_KEY] = to_torch(flags)
        out["terminated"] = to_torch(flags.copy())
        out["done"] = to_torch(flags.copy())
        out["truncated"] = to_torch(np.zeros((n, 1), dtype=bool))
        if self._delay is not None:
            out[APPLIED_ACTION_KEY] = to_torch(self._delay.applied.copy())
        if reward:
            out["reward"] = to_torch(np.zeros((n, 1)))
        return TensorDict._new_unsafe(out, batch_size=self.batch_size, device=device)

    def _differenced(self, arrays: dict[str, np.ndarray] | None = None) -> list[np.ndarray]:
        """The current value of each finite difference's reading, ``[num_envs, size]``."""
        arrays = self._inputs() if arrays is None else arrays
        return [_flat(part.difference_of.compute(arrays), self.num_envs) for part in self._differences]

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
        return action.numpy(force=True)

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(
                f"{self!r} is closed, so it can no longer step or reset. Build a new "
                "env (or deep-copy this one before closing it)."
            )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._check_open()
        action = self._check_action(tensordict.get("action", None))
        skipped = None if np.isfinite(action).all() else ~np.isfinite(action).all(axis=1)
        stepped = None if skipped is None else np.flatnonzero(~skipped)
        if stepped is None:
            np.copyto(self._last_action, action)
        else:  # a skipped env keeps its controls, as it keeps its state
            self._last_action[stepped] = action[stepped]
        # with a delay, the physics run the policy's action of delay[i] steps earlier (only finite ones are queued)
        applied = self._last_action if self._delay is None else self._delay.push(self._last_action, stepped)
        if self._affine:
            declaration = self.declaration
            ctrl = declaration.action_offset + declaration.action_scale * applied
        else:
            ctrl = applied
        if stepped is None:
            np.copyto(self._ctrl, ctrl)
        else:
            self._ctrl[stepped] = ctrl[stepped]
        self.batch.step(stepped, self.frame_skip, self._stage)
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
        arrays = self._inputs()
        differences = []
        for part, previous, now in zip(self._differences, self._previous, self._differenced(arrays), strict=True):
            # a finite difference divides by its own dt where it gives one, else by the env's control timestep
            differences.append((now - previous) / (self.dt if part.dt is None else part.dt))
            np.copyto(previous, now)
        any_broken = bool(broken.any())
        self.__dict__["last_step_broken"] = any_broken
        if not any_broken:
            return self._outputs(differences, None, reward=True, arrays=arrays)
        invalid = [] if skipped is None else np.flatnonzero(skipped).tolist()
        diverged = np.flatnonzero(broken if skipped is None else broken & ~skipped).tolist()
        warnings.warn(
            f"BatchedMujocoEnv({self.declaration.name}): episodes ended by a broken step (terminated=True, "
            f"broken=True, reward 0): non-finite action in envs {invalid}, diverged state in envs {diverged}",
            RuntimeWarning,
            stacklevel=2,
        )
        for difference in differences:
            difference[broken] = 0.0  # no finite difference across a skipped step or MuJoCo's reset
        return self._outputs(differences, broken, reward=True, arrays=arrays)

    def _checked_states(self, value: object, field: str, name: str, rows: np.ndarray, where: str) -> np.ndarray:
        """``value`` as float64 ``[num_envs, nq|nv]`` (``field``: ``"qpos"``/``"qvel"``), its ``rows`` finite."""
        size, count = (self.model.nq, "nq") if field == "qpos" else (self.model.nv, "nv")
        if not isinstance(value, torch.Tensor) or value.dtype != torch.float64 or value.shape != (self.num_envs, size):
            got = f"{value.dtype} {list(value.shape)}" if isinstance(value, torch.Tensor) else repr(value)
            raise ValueError(
                f"{name} must be a float64 tensor of shape [{self.num_envs}, {size}] (num_envs, the model's "
                f"{count}), got {got}"
            )
        values = value.numpy(force=True)
        if not np.isfinite(values[rows]).all():
            raise ValueError(f"{name} must be finite in the rows of {where}")
        return values

    def _given_states(self, tensordict: TensorDictBase | None, ids: np.ndarray) -> dict[str, np.ndarray]:
        """The ``"reset_qpos"``/``"reset_qvel"`` rows of the reset envs ``ids`` (checked), by field."""
        given: dict[str, np.ndarray] = {}
        for field in ("qpos", "qvel") if tensordict is not None else ():
            value = tensordict.get(f"reset_{field}", None)
            if value is not None:
                given[field] = self._checked_states(value, field, f"reset_{field}", ids, "the envs reset")[ids]
        return given

    def set_reset_states(
        self, qpos: torch.Tensor, qvel: torch.Tensor | None = None, mask: torch.Tensor | None = None
    ) -> None:
        """Start the next reset of each env of ``mask`` from the state given here, instead of a drawn one.

        The way to reset to given states wherever TorchRL resets the env (a Collector's partial resets, a
        ``TransformedEnv``): the states wait, per env, for that env's next reset, which consumes them. A running
        episode is not touched. ``"reset_qpos"``/``"reset_qvel"`` entries in the tensordict given to the env's own
        ``reset`` do the same for the envs it resets (TorchRL's ``TransformedEnv`` passes the base env only its
        reset and state entries, so there use this method or a transform's ``_reset_env_preprocess``).

        Args:
            qpos: float64 ``[num_envs, nq]``; the rows of the envs in ``mask`` must be finite.
            qvel: float64 ``[num_envs, nv]``, or ``None``: the reset's default velocities (zeros or the keyframe's).
            mask: bool ``[num_envs]``, the envs to queue states for; ``None``: all.

        Example:
            >>> import torch
            >>> from torchtasks.envs import BatchedMujocoEnv, readings
            >>> xml = '''<mujoco><worldbody><body><joint name="hinge"/><geom size="0.1"/></body></worldbody>
            ...   <actuator><motor joint="hinge"/></actuator></mujoco>'''
            >>> env = BatchedMujocoEnv(xml, 3, observation=readings.joint_pos("hinge"), seed=0)
            >>> qpos = torch.tensor([[0.5], [1.0], [1.5]], dtype=torch.float64)
            >>> env.set_reset_states(qpos, mask=torch.tensor([False, True, True]))
            >>> env.reset()["observation"][:, 0].tolist()  # env 0 draws (no noise declared: qpos0)
            [0.0, 1.0, 1.5]
            >>> env.reset()["observation"][:, 0].tolist()  # consumed: the next reset draws again
            [0.0, 0.0, 0.0]
        """
        envs = np.ones(self.num_envs, dtype=bool) if mask is None else self._checked_mask(mask, "mask")
        rows = {
            field: self._checked_states(value, field, f"set_reset_states: {field}", envs, "the envs in mask")
            for field, value in (("qpos", qpos), ("qvel", qvel))
            if value is not None
        }
        self._queued_qpos[envs] = rows["qpos"][envs]
        self._queued_qvel[envs] = rows["qvel"][envs] if "qvel" in rows else np.nan

    def _checked_mask(self, mask: object, argument: str) -> np.ndarray:
        if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool or mask.shape != (self.num_envs,):
            got = f"{mask.dtype} {list(mask.shape)}" if isinstance(mask, torch.Tensor) else repr(mask)
            raise ValueError(f"{argument} must be a bool tensor of shape [{self.num_envs}] (num_envs), got {got}")
        return mask.cpu().numpy().copy()

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        """Reset the masked envs (all without a mask) to a drawn state (:class:`Resets`) or a given one."""
        self._check_open()
        reset = None if tensordict is None else tensordict.get("_reset", None)
        ids = None if reset is None else np.flatnonzero(reset.reshape(self.num_envs).cpu().numpy())
        if ids is not None and ids.size == self.num_envs:
            ids = None
        if ids is None or ids.size:
            rows = slice(None) if ids is None else ids
            all_ids = np.arange(self.num_envs) if ids is None else ids
            given = self._given_states(tensordict, all_ids)
            resets = self.declaration.resets
            self.batch.reset(ids, keyframe=resets.keyframe, stage=mujoco.mjtStage.mjSTAGE_NONE)  # mj_resetData
            if given:  # the reset tensordict's states, for every env reset
                for field, values in given.items():
                    (self._qpos if field == "qpos" else self._qvel)[all_ids] = values
                self._run_steps(all_ids, state=False)
            else:  # the states set_reset_states queued, for the envs it queued them for; the others draw
                queued = ~np.isnan(self._queued_qpos[all_ids, 0])  # a NaN row: nothing queued
                drawn = all_ids[~queued] if queued.any() else all_ids
                if drawn.size:
                    self._draw(drawn, rows if drawn is all_ids else drawn)
                if queued.any():
                    started = all_ids[queued]
                    self._run_steps(started, state=False)
                    self._qpos[started] = self._queued_qpos[started]
                    velocities = started[np.isfinite(self._queued_qvel[started]).all(axis=1)]
                    self._qvel[velocities] = self._queued_qvel[velocities]
            self._queued_qpos[all_ids] = np.nan
            self._queued_qvel[all_ids] = np.nan
            self.batch.forward(ids)
            self._read_outputs(ids, post_constraint=False)
            self._time[rows] = self._clock[rows]
            self._last_action[rows] = 0.0
            if self._delay is not None:  # the delay set since the last reset starts with this episode
                pending = self._domain.values.get(ACTION_DELAY)
                self._delay.reset(rows, 0 if pending is None else pending[rows])
            for previous, now in zip(self._previous, self._differenced(), strict=True):
                previous[rows] = now[rows]
        return self._outputs(None, None, reward=False)

    def _reset_context(self) -> ResetContext:
        """What the reset steps (:mod:`~torchtasks.envs.reset_steps`) work on: this env's batch."""
        context = self.__dict__.get("_context")
        if context is None:
            batch = self.batch

            def write_domain(name: str, ids: np.ndarray, values: np.ndarray) -> None:
                self._follow_domain(self._domain.write({name: values}, ids), ids)

            def settle(ids: np.ndarray, nstep: int) -> None:
                batch.step(ids, nstep, self._stage)
                self._clock[ids] = 0.0

            context = ResetContext(self.model, self._qpos, self._qvel, batch.bind, batch.forward, write_domain, settle)
            self.__dict__["_context"] = context
        return context

    def _run_steps(self, ids: np.ndarray, state: bool) -> None:
        """Run the declaration's reset steps for the reset envs ``ids`` (only the parts that write model fields
        alone unless ``state``: a reset to given states)."""
        steps = [
            apply if state else model_part
            for _, apply, model_part in self.declaration.reset_steps
            if state or model_part is not None
        ]
        if steps:
            context, generators = self._reset_context(), [self.np_random[i] for i in ids.tolist()]
            for apply in steps:
                apply(context, ids, generators)

    def _draw(self, ids: np.ndarray, rows: slice | np.ndarray) -> None:
        """Draw the reset envs' initial states from their generators and write them over the default state."""
        self._draw_noise(ids, rows)
        self._run_steps(ids, state=True)

    def _draw_noise(self, ids: np.ndarray, rows: slice | np.ndarray) -> None:
        resets = self.declaration.resets
        if not resets.noise and resets.free_joint is None:
            return
        # The other Python loop over envs, over the reset ones: each draws from its own generator, in the declared
        # order, so an env's draws do not depend on which other envs reset (and Gymnasium's per-env draws are
        # reproduced); the draws are then applied as arrays. Measured 2026-12-02 (load ~2): 2.5-5 us per env, 12 of
        # 311 us for one quadruped env's reset, 158 of 1,867 us for 64, Hopper 306 of 1,134 us for 64.
        generators = [self.np_random[i] for i in ids.tolist()]
        draws = [[noise.draw(rng, columns.size) for _, columns, noise in resets.noise] for rng in generators]
        targets = {"qpos": self._qpos, "qvel": self._qvel}
        for k, (target, columns, noise) in enumerate(resets.noise):
            values = np.array([draw[k] for draw in draws])
            array, cells = targets[target], np.ix_(ids, columns)
            if noise.mode == "add":
                array[cells] = array[cells] + values
            else:
                array[cells] = array[cells] * (1.0 + values)
        if resets.free_joint is not None:
            qpos_adr, dof_adr, ranges = resets.free_joint
            free = np.array([_free_joint_draw(rng, ranges) for rng in generators])  # [k, 10]
            position = self._qpos[rows, qpos_adr : qpos_adr + 3] + free[:, 0:3]
            yaw = free[:, 3]
            turn = np.stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2)], axis=1)
            quaternion = _quaternion_product(turn, self._qpos[rows, qpos_adr + 3 : qpos_adr + 7])
            self._qpos[rows, qpos_adr : qpos_adr + 3] = position
            self._qpos[rows, qpos_adr + 3 : qpos_adr + 7] = quaternion
            self._qvel[rows, dof_adr : dof_adr + 6] = self._qvel[rows, dof_adr : dof_adr + 6] + free[:, 4:10]

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
        if names is not None and not isinstance(names, (str, bytes)) and isinstance(names, Sequence):
            self._refuse_absent(names)
        return self._domain.fields(names)

    def _refuse_absent(self, names: Iterable[object]) -> None:
        for name in names:
            reason = self.absent_field_reason(name)
            if reason is not None:
                raise ValueError(f"BatchedMujocoEnv: {reason}")

    def absent_field_reason(self, name: object) -> str | None:
        """Why ``name`` is not a domain field of this env although envs of its kind offer it, or ``None``.

        ``"action_delay"`` is a field only of an env built with ``max_action_delay > 0``.

        Example:
            >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=1)
            >>> env.absent_field_reason("action_delay")[:47]
            "'action_delay' is a domain field only of an env"
            >>> env.close()
        """
        if name == ACTION_DELAY and not self.max_action_delay:
            return (
                f"{ACTION_DELAY!r} is a domain field only of an env built with max_action_delay > 0 (the largest "
                "delay in steps, e.g. BatchedMujocoEnv(..., max_action_delay=2)); this env has max_action_delay=0"
            )
        return None

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give the envs of ``mask`` the physics ``values[name][i]``, from their next step or reset on.

        ``"action_delay"`` (``max_action_delay > 0``) takes effect at each env's next reset only: a running episode
        keeps its delay. The values persist until set again (resets keep them) and checkpoints keep them. Only the
        model fields of the kinds written become per-env (``Batch.expand``), and ``Batch.set_const`` runs once over
        the envs written if some field written needs it (masses, armatures, gears). A running episode continues from
        its state.

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
        if isinstance(values, Mapping):
            self._refuse_absent(values)
        rows, ids = self._domain.checked(values, mask, "values")
        if rows and (ids is None or ids.size):
            self._follow_domain(self._domain.write(rows, ids), ids)

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's current value of each field named (``None``: all), as float64 ``[num_envs, *value_shape]``.

        A field never set holds its nominal value. An object's model value is its value times its kind's scale.
        ``"action_delay"`` is the value set last: the delay of each env's next episode (and of its running one, unless
        it was set during that episode).

        Example:
            >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=2)
            >>> env.domain_values(["gravity"])["gravity"]
            tensor([[ 0.0000,  0.0000, -9.8100],
                    [ 0.0000,  0.0000, -9.8100]], dtype=torch.float64)
            >>> env.close()
        """
        device = self.device
        return {name: torch.from_numpy(value).to(device) for name, value in self._domain.read(names).items()}

    # ------------------------------------------------------------------ pushes
    def pushable_bodies(self) -> tuple[str, ...]:
        """The bodies whose velocity :meth:`add_body_velocity` can change: the named bodies with a free joint.

        Example:
            >>> from torchtasks.envs import readings
            >>> from torchtasks.envs.models import model_path
            >>> env = BatchedMujocoEnv(model_path("quadruped"), 2, observation=readings.joint_pos(), seed=0)
            >>> env.pushable_bodies()  # the torso; the legs' bodies hang on hinges
            ('torso',)
            >>> env.close()
        """
        return self._pushes.free_bodies

    def add_body_velocity(self, body: str, delta: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        """Add ``delta[i]`` to the velocity of ``body``'s free joint in each env ``i`` of ``mask``, from its next step.

        MuJoCo's free-joint velocity: ``delta[:, :3]`` changes the linear velocity of the body's origin in the world
        frame (m/s), ``delta[:, 3:]`` the angular velocity in the body's own frame (rad/s). The change is a write
        into the envs' state, as a reset's: the next step's physics starts from it (the readings of the env show it
        after that step), and a checkpoint taken before that step keeps it.

        Args:
            body: a body of :meth:`pushable_bodies` (``ValueError`` naming the close ones otherwise).
            delta: float64 ``[num_envs, 6]``; the rows of the envs in ``mask`` must be finite, the others are ignored.
            mask: bool ``[num_envs]``, the envs to push; ``None``: all.

        Example:
            >>> import torch
            >>> from torchtasks.envs import readings
            >>> from torchtasks.envs.models import model_path
            >>> env = BatchedMujocoEnv(model_path("quadruped"), 2, observation=readings.joint_pos(), seed=0)
            >>> _ = env.reset()
            >>> delta = torch.tensor([[1.0, 0, 0, 0, 0, 0], [0, 2.0, 0, 0, 0, 0]], dtype=torch.float64)
            >>> env.add_body_velocity("torso", delta, mask=torch.tensor([False, True]))
            >>> env.batch.bind("qvel")[:, :3].tolist()
            [[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]]
            >>> env.close()
        """
        self._check_open()
        self._pushes.add_velocity(self._qvel, body, delta, self._push_mask(mask, "add_body_velocity: mask"))

    def set_body_wrench(self, body: str, wrench: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        """Apply the wrench ``wrench[i]`` to ``body`` in each env ``i`` of ``mask``, from its next step until set again.

        MuJoCo's ``xfrc_applied``: ``wrench[:, :3]`` is a force (N), ``wrench[:, 3:]`` a torque (N m), both in the
        world frame, applied at the body's centre of mass. The wrench is part of the envs' state: it stays over
        steps until set again (zeros remove it), a checkpoint keeps it, and an env's reset clears it.

        Args:
            body: the name of a body other than the world (``ValueError`` naming the close ones otherwise).
            wrench: float64 ``[num_envs, 6]``; the rows of the envs in ``mask`` must be finite, the others are ignored.
            mask: bool ``[num_envs]``, the envs to write; ``None``: all.

        Example:
            >>> import torch
            >>> from torchtasks.envs import readings
            >>> from torchtasks.envs.models import model_path
            >>> env = BatchedMujocoEnv(model_path("quadruped"), 2, observation=readings.joint_pos(), seed=0)
            >>> data = env.reset()
            >>> push = torch.tensor([[0.0, 0, 5, 0, 0, 0], [0, 0, 9, 0, 0, 1]], dtype=torch.float64)
            >>> env.set_body_wrench("torso", push, mask=torch.tensor([False, True]))
            >>> env.batch.bind("xfrc_applied")[:, 1].tolist()  # body 1 is "torso"
            [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 9.0, 0.0, 0.0, 1.0]]
            >>> _ = env.rand_step(data)  # applied in this step, and the next ones
            >>> _ = env.reset()  # a reset clears it
            >>> env.batch.bind("xfrc_applied")[1, 1].tolist()
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            >>> env.close()
        """
        self._check_open()
        mask = self._push_mask(mask, "set_body_wrench: mask")
        self._pushes.set_wrench(self._xfrc_applied, body, wrench, mask)

    def _push_mask(self, mask: torch.Tensor | None, argument: str) -> np.ndarray:
        return np.ones(self.num_envs, dtype=bool) if mask is None else self._checked_mask(mask, argument)

    def _follow_domain(self, kinds: set[FieldKind], ids: np.ndarray | None) -> None:
        """Update what the env keeps of the model beside the batch, for the envs ``ids`` whose ``kinds`` were written.

        Gymnasium's Ant and Humanoid: each env's model, for its contact forces (:meth:`_read_outputs`). A finite
        difference of a reading of the fields written (Humanoid's mass centre reads the masses): the value the next
        step differences from, with the new fields (as Gymnasium's step reads ``body_mass`` before and after it).
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
        written = {name for kind in kinds for name in kind.model_fields}
        followed = [k for k, part in enumerate(self._differences) if written & set(_model_fields(part))]
        if followed:
            rows = slice(None) if ids is None else ids
            now = self._differenced()
            for k in followed:
                self._previous[k][rows] = now[k][rows]

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
            # a Gymnasium id, or None for a model of the user's: not its file's path, so that a checkpoint loads into
            # an env of the same model read from another place (another checkout, machine or MjSpec); the compiled
            # model's hash tells models apart
            "env_id": self.env_id,
            "num_envs": self.num_envs,
            "frame_skip": self.frame_skip,
            "model_sha256": hashlib.sha256(binary.tobytes()).hexdigest(),
            # absent without a delay: as checkpoints written before the env had one
            **({"max_action_delay": self.max_action_delay} if self.max_action_delay else {}),
            # a model of the user's: what the env reads, how it acts and resets (a preset's id and keywords say it)
            **({} if self.env_id is not None else {"declaration": self._declaration_facts()}),
        }

    def _declaration_facts(self) -> str:
        """The declaration's readings, action map, resets and stage, as text (compared by a load)."""
        declaration, resets = self.declaration, self.declaration.resets
        noise = [(target, columns.tolist(), each) for target, columns, each in resets.noise]
        return repr(
            {
                "observation": dict(declaration.observation_readings),
                "state": dict(declaration.state_readings),
                "action_scale": declaration.action_scale.tolist(),
                "action_offset": declaration.action_offset.tolist(),
                "reset_keyframe": resets.keyframe,
                "reset_noise": noise,
                "free_joint": resets.free_joint,
                **({"reset_steps": resets.steps} if resets.steps else {}),  # absent: as checkpoints written before
                "stage": declaration.stage,
            }
        )

    def _previous_values(self) -> np.ndarray:
        """The finite differences' previous values side by side, ``[num_envs, total size]``."""
        if not self._previous:
            return np.zeros((self.num_envs, 0))
        return np.concatenate(self._previous, axis=1)

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
            "previous_position": torch.from_numpy(self._previous_values()),
            "last_action": torch.from_numpy(self._last_action.copy()),
            "queued_qpos": torch.from_numpy(self._queued_qpos.copy()),
            "queued_qvel": torch.from_numpy(self._queued_qvel.copy()),
            "gathered": [torch.from_numpy(array.copy()) for array in gathered],
            _DOMAIN_KEY: self._domain.saved(),
            **({} if self._delay is None else self._delay.saved()),
        }

    def _checked_running_episodes(self, running: Any, owner: str) -> dict[str, Any]:
        """``running`` as :meth:`_running_episodes` wrote it for this env; else a ``ValueError`` naming both sides."""
        delayed = SAVED_KEYS if self._delay is not None else ()
        expected = f"a dict of {list(_RUNNING_KEYS + delayed)} (and {_DOMAIN_KEY!r})"
        if not isinstance(running, Mapping) or not isinstance(running.get("model"), Mapping):
            got = sorted(running) if isinstance(running, Mapping) else type(running).__name__
            raise ValueError(f"{owner}: 'running_episodes' must be {expected}, got {got}")
        mine = self._running_episodes()
        # the simulation first (its facts say why the other entries may differ: another model, max_action_delay, ...)
        saved_model, own_model = dict(running["model"]), mine["model"]
        if saved_model != own_model:
            differ = sorted(
                key for key in own_model.keys() | saved_model.keys() if saved_model.get(key) != own_model.get(key)
            )
            # the facts that differ only: the declaration alone runs to thousands of characters
            saved = {key: saved_model.get(key) for key in differ}
            own = {key: own_model.get(key) for key in differ}
            raise ValueError(
                f"{owner}: the saved running episodes are of another simulation ({', '.join(differ)} differ): "
                f"saved {saved}, this env {own}; load a checkpoint of an env built as this one"
            )
        if set(running) - {_DOMAIN_KEY, *_OPTIONAL_RUNNING_KEYS} != set(_RUNNING_KEYS + delayed):
            raise ValueError(f"{owner}: 'running_episodes' must be {expected}, got {sorted(running)}")
        if not isinstance(running["gathered"], Sequence) or len(running["gathered"]) != len(mine["gathered"]):
            raise ValueError(
                f"{owner}: 'gathered' must be a list of {len(mine['gathered'])} tensors for this env, "
                f"got {running['gathered']!r}"
            )
        names = ["integration_state", "warnings", "time", "previous_position", *delayed]
        names += [name for name in _OPTIONAL_RUNNING_KEYS if name in running]
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
        if self._delay is not None:
            self._delay.check_saved(running, owner)
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
        previous = running["previous_position"].cpu().numpy()
        start = 0
        for values in self._previous:
            values[:] = previous[:, start : start + values.shape[1]]
            start += values.shape[1]
        self._last_action[:] = running["last_action"].cpu().numpy() if "last_action" in running else 0.0
        for name, array in (("queued_qpos", self._queued_qpos), ("queued_qvel", self._queued_qvel)):
            array[:] = running[name].cpu().numpy() if name in running else np.nan
        for (array, _), values in zip(self._readers, running["gathered"][1:], strict=True):
            array[:] = values.cpu().numpy()
        if self._delay is not None:
            self._delay.load(running)

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
            f"{type(self).__name__}({self.declaration.name}, num_envs={self.num_envs}, "
            f"num_threads={self.num_threads}, frame_skip={self.frame_skip}, device={self.device}"
            + (f", max_action_delay={self.max_action_delay})" if self.max_action_delay else ")")
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
