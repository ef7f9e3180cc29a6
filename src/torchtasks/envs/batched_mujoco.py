"""Batched Gymnasium MuJoCo v5 locomotion envs in one process: one ``MjModel``, one ``MjData`` per env, native threads.

:class:`BatchedMujocoEnv` steps ``num_envs`` copies of a Gymnasium v5 locomotion env (HalfCheetah,
Hopper, Walker2d, Swimmer, Ant, Humanoid) as one TorchRL env with ``batch_size=[num_envs]``. The
model is the one Gymnasium builds for the same keyword arguments, each step applies
``ctrl = action`` and advances ``frame_skip`` MuJoCo substeps per env in a small pool of threads
(``mujoco.mj_step`` releases the GIL), and the observation is computed for all envs at once from
stacked numpy arrays, exactly as Gymnasium v5 computes it for one env. Rewards and terminations
come from a task: the env writes the entries :func:`~torchtasks.envs.locomotion.locomotion_state_layout`
lists, so ``TaskTransform(locomotion_task(env_id, **kw), state_key=[...])`` reproduces Gymnasium's
reward, its terms and its ``terminated`` (``gymnasium_env(env_id, num_envs=N)`` builds that stack).

Why threads over ``mj_step`` and not ``mujoco.rollout``: ``rollout`` takes and returns the
``mjSTATE_FULLPHYSICS`` state, which lacks the constraint solver's warm start (``qacc_warmstart``)
that a Gymnasium env carries from one step to the next (``initial_warmstart`` can be passed in, the
final one is not returned). Restarting every step from another warm start moves the solution within
the solver's tolerance and the difference grows until the trajectories part (HalfCheetah: 4e-12 in
``qpos`` after 50 steps, 0.25 after 150; with the exact warm start passed in, rollout is bit-identical).
It also returns no ``xpos``/``xipos``/``cfrc_ext``, which the forward and contact terms read. On an
idle 2-core machine both run at the same speed (HalfCheetah ×64: 59-64k frames/s threaded,
62-65k rollout); when other processes compete for the cores, the per-env GIL hand-offs of the threads
cost more (measured 13-17k against 38-44k). ``benchmarks/batched_mujoco.py`` measures both.
"""

from __future__ import annotations

import copy
import hashlib
import os
import warnings
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
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
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.batched_mujoco (BatchedMujocoEnv)", _error) from _error

from torchtasks.envs.gymnasium_v5 import LocomotionEnvRecord, ModelFacts, gymnasium_config, locomotion_record

__all__ = ["BatchedMujocoEnv", "ZeroBrokenStepReward"]

#: the entry that marks a broken step (bool ``[num_envs, 1]``, observation spec)
BROKEN_KEY = "broken"

#: MuJoCo warnings raised when it resets a diverged state itself (mj_checkPos/Vel/Acc)
_DIVERGENCE_WARNINGS = (
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
)
#: what one ``mj_getState`` call gathers per env: ``[time, qpos, qvel]``
_STATE_SPEC = int(mujoco.mjtState.mjSTATE_TIME | mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL)
#: what a checkpoint, a copy or a pickle of the env keeps of each ``MjData``: everything ``mj_step`` starts from
#: (time, qpos, qvel, act, the constraint solver's warm start, ctrl, applied forces, mocap, ...), so a restored
#: env continues the same trajectory bit for bit
_INTEGRATION_STATE = int(mujoco.mjtState.mjSTATE_INTEGRATION)
#: the entries of the running-episode state (``state_dict()["_extra_state"]["running_episodes"]``)
_RUNNING_KEYS = ("model", "integration_state", "warnings", "time", "previous_position", "gathered")
#: attributes rebuilt when a copy or a pickle is restored: the thread pool (threads cannot be copied), the
#: MjData (restored from their integration state on the one MjModel) and the gather buffers with the
#: observation plan (numpy views of each other, which a copy would turn into independent arrays)
_REBUILT = ("_pool", "datas", "_state", "_readers", "_observation_plan", "_entry_sources", "_position", "_mass_weights")


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

    One ``mujoco.MjModel``, built by Gymnasium for ``env_id`` and ``gym_kwargs`` (``xml_file``,
    ``frame_skip`` and every keyword that changes the dynamics or the observation), and one
    ``mujoco.MjData`` per env. A step sets ``ctrl = action`` (as Gymnasium: not clipped; MuJoCo
    clamps it to ``ctrlrange``), runs ``mj_step(model, data, nstep=frame_skip)`` (and
    ``mj_rnePostConstraint`` for Ant and Humanoid, as Gymnasium does) for every env, split over
    ``num_threads`` threads, and computes Gymnasium v5's observation for all envs from stacked
    arrays. With the same states and actions, the observation equals Gymnasium's bit for bit.

    Entries (float64, ``[num_envs, size]``):

    - ``"observation"``: Gymnasium's observation for these keywords (e.g. without the x position
      by default, Hopper's and Walker2d's velocities clipped to ±10, Ant's clipped contact forces).
    - the task state of :func:`~torchtasks.envs.locomotion.locomotion_state_layout` (or the
      entries ``task_state_keys`` names), a subset of ``"x_velocity"``, ``"y_velocity"`` (Swimmer, Ant,
      Humanoid), ``"qpos"``, ``"qvel"`` (unclipped) and ``"cfrc_ext"`` (all bodies, flattened).
      ``"x_velocity"`` and ``"y_velocity"`` are Gymnasium's ``info`` entries: ``qpos[0]``
      (HalfCheetah, Hopper, Walker2d; Swimmer ``qpos[0:2]``), Ant's main-body ``xpos[:2]`` or
      Humanoid's centre of mass (from ``xipos``; these two lag ``qpos`` by one substep, like
      Gymnasium's) finite-differenced over the step exactly as Gymnasium does; 0 after a reset.

    The env pays no reward (``"reward"`` is 0, float64) and ends no episode by itself: put a
    :class:`~torchtasks.transforms.TaskTransform` of
    :func:`~torchtasks.envs.locomotion.locomotion_task` on it (with ``StepCounter(1000)`` for
    Gymnasium's time limit), or use ``gymnasium_env(env_id, num_envs=N)``, which does. The one
    exception is a broken step: an env whose action has a non-finite entry is not simulated, and an
    env whose state diverges (MuJoCo then resets it to ``qpos0`` by itself; it is detected from the
    simulation time running back, the divergence warnings and non-finite states) is not continued;
    both end with ``terminated = done = True`` and a ``RuntimeWarning``, and the next reset starts a
    fresh episode. Gymnasium would continue silently from MuJoCo's reset state.

    What a broken step writes, so that one broken env cannot poison a training batch: ``"broken"``
    (bool ``[num_envs, 1]``, in the observation spec, so collectors keep it) is True for that env
    only (and False at every reset); its reward is 0; its ``"x_velocity"`` is 0; its observation
    and state entries are finite (the state before the step for a skipped action, MuJoCo's
    ``qpos0`` reset for a diverged state; a non-finite state is reset to ``qpos0`` here, as MuJoCo
    does). A task on the env still reads the policy's non-finite action (a control cost of NaN):
    put :class:`ZeroBrokenStepReward` after the ``TaskTransform`` and before ``RewardSum`` (as
    ``gymnasium_env`` does) to pay 0 for the broken step in the reward and every term. Filter
    ``("next", "broken")`` out of statistics that should count only real episodes.

    ``copy.deepcopy(env)`` and ``pickle`` give an independent env in the same state (MuJoCo states
    with the solver's warm start, warning counters, generators, episode clocks) with its own threads:
    stepped with the same actions, it continues the same trajectories bit for bit. After
    ``env.close()`` (which stops the threads) stepping or resetting raises a ``RuntimeError``.

    Resets draw Gymnasium v5's initial state distribution of ``env_id`` (``init_qpos`` plus uniform
    noise of half-width ``reset_noise_scale``, ``init_qvel`` plus uniform or, for HalfCheetah and
    Ant, normal noise), from one numpy generator per env (``np_random``, spawned from
    ``numpy.random.SeedSequence(seed)``), and do what Gymnasium's ``reset`` does to the ``MjData``
    (``mj_resetData``, then ``qpos``/``qvel``, then ``mj_forward``). Partial resets (TorchRL's
    ``"_reset"`` mask) reset only the masked envs.

    Checkpoints: ``env.state_dict()`` holds, under ``"_extra_state"``, the ``num_envs`` reset
    generators (each numpy ``bit_generator.state``) and the running episodes: every env's
    ``mjSTATE_INTEGRATION`` state (with the solver's warm start), its MuJoCo warning counters, the
    episode clocks and last forward positions (what the velocities are finite-differenced from) and
    the gathered arrays (the observation of envs a partial reset leaves alone is read from them), as
    float64/int64 tensors. After ``load_state_dict`` every env draws the initial states that the
    saved one would have drawn next and a step continues the saved episodes, bit for bit (the
    collector's carried data, the last observation, is :func:`torchtasks.checkpoint.collector_state`'s).
    A load is refused (``ValueError`` naming both sides) unless the env has the same ``env_id``,
    ``num_envs``, ``frame_skip`` and MuJoCo model (a digest of its compiled binary). TorchRL's
    ``Collector.state_dict()`` and ``TransformedEnv.state_dict()`` save the transforms of a
    ``TransformedEnv``, not its base env: put a :class:`~torchtasks.checkpoint.BaseEnvState` in it.

    Args:
        env_id: one of :data:`~torchtasks.envs.locomotion.SUPPORTED_ENV_IDS`.
        num_envs: number of environments.
        seed: seed of the per-env generators (``set_seed`` reseeds them); ``None``: fresh entropy.
        device: device of the output tensors (the simulation runs on the CPU); ``env.to(device)``
            moves them.
        num_threads: threads that step the envs (the calling thread included); default: the CPUs
            this process may use, at most ``num_envs``.
        task_state_keys: the task-state entries to write, in order (default: the env record's
            ``state_keys``, what :func:`~torchtasks.envs.locomotion.locomotion_task` reads; the safety
            presets add ``"y_velocity"`` for Ant and Humanoid).
        **gym_kwargs: the env's Gymnasium keyword arguments (validated as by
            :func:`~torchtasks.envs.locomotion.locomotion_task`, e.g. ``reset_noise_scale`` must be a
            finite, non-negative number). Rendering is not supported.

    Example:
        >>> from torchtasks.envs import BatchedMujocoEnv
        >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=2, seed=0)
        >>> rollout = env.rollout(3)
        >>> rollout["next", "observation"].shape, rollout["next", "qpos"].dtype
        (torch.Size([2, 3, 11]), torch.float64)
        >>> fresh = BatchedMujocoEnv("Hopper-v5", num_envs=2)
        >>> fresh.load_state_dict(env.state_dict())
        <All keys matched successfully>
        >>> bool((fresh.reset()["qpos"] == env.reset()["qpos"]).all())
        True
        >>> env.close(); fresh.close()
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
        self.datas = [mujoco.MjData(self.model) for _ in range(num_envs)]
        self.state_layout = record.state_layout(facts, self.task_state_keys)
        self.reset_noise_scale = float(config["reset_noise_scale"])
        self._setup_buffers()
        if self._observation_size != facts.observation_size:  # a Gymnasium version that observes differently
            raise RuntimeError(
                f"{env_id}: the batched observation has {self._observation_size} entries but Gymnasium's has "
                f"{facts.observation_size}; this Gymnasium version is not supported by BatchedMujocoEnv"
            )
        self._chunks = [(int(c[0]), int(c[-1]) + 1) for c in np.array_split(np.arange(num_envs), num_threads)]
        self._closed = False
        self._pool: ThreadPoolExecutor | None = None
        self._start_threads()
        self._make_specs(facts)
        self.np_random: list[np.random.Generator] = []
        self._set_seed(seed)

    # ------------------------------------------------------------------ set-up
    def _setup_buffers(self) -> None:
        """Allocate the per-env gather buffers and plan the observation as copies from them (as the record says)."""
        record, config, model, n = self._record, self._config, self.model, self.num_envs
        nq = model.nq
        self._state = np.zeros((n, mujoco.mj_stateSize(model, _STATE_SPEC)))  # [time, qpos, qvel]
        self._time = np.zeros(n)
        self._half_timestep = 0.5 * float(model.opt.timestep)
        #: (MjData attribute, index or None, buffer): buffer[i] = data.<attribute>[index] after every step
        self._readers: list[tuple[str, Any, np.ndarray]] = []

        def reader(attribute: str, index: Any = None) -> np.ndarray:
            value = getattr(self.datas[0], attribute)
            buffer = np.zeros((n, *np.shape(value if index is None else value[index])))
            self._readers.append((attribute, index, buffer))
            return buffer

        # one buffer per MjData array that the task state or the observation reads
        arrays = {"qpos": self._state[:, 1 : 1 + nq], "qvel": self._state[:, 1 + nq :]}

        def array(attribute: str) -> np.ndarray:
            if attribute not in arrays:
                arrays[attribute] = reader(attribute)
            return arrays[attribute]

        # the task-state entries, as views of the gather buffers (the velocities are computed)
        self._entry_sources: dict[str, np.ndarray | None] = {
            key: None if key in record.velocity_keys else array(key).reshape(n, -1) for key in self.task_state_keys
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
            source = array(part.source)[:, part.start :].reshape(n, -1)
            self._observation_plan.append((slice(start, start + source.shape[1]), source, part.clip))
            start += source.shape[1]
        self._observation_size = start
        # Gymnasium calls mj_rnePostConstraint after every step; only the contact forces need it here
        self._rne = "cfrc_ext" in arrays

    def _start_threads(self) -> None:
        """Start the pool of ``num_threads - 1`` threads (the calling thread steps the first share itself)."""
        if self.num_threads > 1:
            self._pool = ThreadPoolExecutor(self.num_threads - 1, "batched-mujoco")

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
    def _gather(self, i: int, data: mujoco.MjData) -> None:
        mujoco.mj_getState(self.model, data, self._state[i], _STATE_SPEC)
        for attribute, index, buffer in self._readers:
            value = getattr(data, attribute)
            buffer[i] = value if index is None else value[index]

    def _advance(self, start: int, stop: int, ctrl: np.ndarray, skipped: np.ndarray | None) -> None:
        """Step envs ``start:stop`` (those not ``skipped``) and gather their state (one thread's share)."""
        model, datas, nstep, rne = self.model, self.datas, self.frame_skip, self._rne
        step, post_constraint, gather = mujoco.mj_step, mujoco.mj_rnePostConstraint, self._gather
        for i in range(start, stop):
            data = datas[i]
            if skipped is None or not skipped[i]:
                data.ctrl[:] = ctrl[i]
                step(model, data, nstep)
                if rne:
                    post_constraint(model, data)
            gather(i, data)

    def _simulate(self, ctrl: np.ndarray, skipped: np.ndarray | None) -> None:
        chunks = self._chunks
        if self._pool is None:
            self._advance(0, self.num_envs, ctrl, skipped)
            return
        futures = [self._pool.submit(self._advance, start, stop, ctrl, skipped) for start, stop in chunks[1:]]
        self._advance(*chunks[0], ctrl, skipped)
        for future in futures:
            future.result()

    def _forward(self, data: mujoco.MjData) -> None:
        """Recompute what depends on the state (``mj_forward``, and the contact forces where Gymnasium reads them)."""
        mujoco.mj_forward(self.model, data)
        if self._rne:
            mujoco.mj_rnePostConstraint(self.model, data)

    def _reset_env(self, i: int) -> None:
        """Gymnasium v5's ``reset`` of env ``i`` (``mj_resetData``, ``reset_model``) and a gather of its state."""
        model, data, rng, scale = self.model, self.datas[i], self.np_random[i], self.reset_noise_scale
        mujoco.mj_resetData(model, data)
        qpos = self.init_qpos + rng.uniform(low=-scale, high=scale, size=model.nq)
        if self._record.velocity_noise == "normal":
            qvel = self.init_qvel + scale * rng.standard_normal(model.nv)
        else:
            qvel = self.init_qvel + rng.uniform(low=-scale, high=scale, size=model.nv)
        data.qpos[:] = qpos
        data.qvel[:] = qvel
        mujoco.mj_forward(model, data)
        self._gather(i, data)

    def _restart_env(self, i: int) -> None:
        """Put env ``i``, whose state is not finite, back to ``qpos0`` as MuJoCo does with a diverged state."""
        data = self.datas[i]
        mujoco.mj_resetData(self.model, data)
        self._forward(data)
        self._gather(i, data)

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
        return action.detach().to("cpu", torch.float64).numpy()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(
                f"{self!r} is closed: close() stopped its threads, so it can no longer step or reset. Build a new "
                "env (or deep-copy this one before closing it)."
            )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._check_open()
        ctrl = self._check_action(tensordict.get("action", None))
        skipped = None if np.isfinite(ctrl).all() else ~np.isfinite(ctrl).all(axis=1)
        previous_time = self._time
        self._simulate(ctrl, skipped)
        state = self._state
        restarted = None
        if not np.isfinite(state).all():  # not caught by MuJoCo's own checks: restart it as MuJoCo would
            restarted = ~np.isfinite(state).all(axis=1)
            for i in np.flatnonzero(restarted):
                self._restart_env(int(i))
        time = state[:, 0].copy()
        self._time = time
        # MuJoCo resets a diverged state to qpos0 and time 0 by itself: the clock runs back. The first
        # substep after one of our resets (time 0) cannot show it, so read its warnings there.
        broken = time < previous_time + self._half_timestep
        for i in np.flatnonzero(previous_time == 0.0):
            warning = self.datas[i].warning
            broken[i] = broken[i] or any(warning[w].number for w in _DIVERGENCE_WARNINGS)
        if restarted is not None:
            broken |= restarted
        if skipped is not None:
            broken |= skipped
        position = self._forward_position()
        velocity = (position - self._previous_position) / self.dt
        self._previous_position = position
        self.last_step_broken = bool(broken.any())
        if not self.last_step_broken:
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
        self._check_open()
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is None:
            indices = range(self.num_envs)
        else:
            indices = np.flatnonzero(reset.reshape(self.num_envs).cpu().numpy())
        for i in indices:
            self._reset_env(int(i))
        self._time[indices] = self._state[indices, 0]
        self._previous_position[indices] = self._forward_position()[indices]
        return self._outputs(None, None, reward=False)

    def _set_seed(self, seed: int | None) -> None:
        children = np.random.SeedSequence(None if seed is None else int(seed)).spawn(self.num_envs)
        self.np_random = [np.random.Generator(np.random.PCG64(child)) for child in children]

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
        model, n = self.model, self.num_envs
        integration = np.empty((n, mujoco.mj_stateSize(model, _INTEGRATION_STATE)))
        counters = np.empty((n, len(self.datas[0].warning)), dtype=np.int64)
        for i, data in enumerate(self.datas):
            mujoco.mj_getState(model, data, integration[i], _INTEGRATION_STATE)
            counters[i] = [warning.number for warning in data.warning]
        gathered = [self._state, *(buffer for _, _, buffer in self._readers)]
        return {
            "model": self._model_facts(),
            "integration_state": torch.from_numpy(integration),
            "warnings": torch.from_numpy(counters),
            "time": torch.from_numpy(self._time.copy()),
            "previous_position": torch.from_numpy(np.array(self._previous_position)),
            "gathered": [torch.from_numpy(array.copy()) for array in gathered],
        }

    def _checked_running_episodes(self, running: Any, owner: str) -> dict[str, Any]:
        """``running`` as :meth:`_running_episodes` wrote it for this env; else a ``ValueError`` naming both sides."""
        if not isinstance(running, Mapping) or set(running) != set(_RUNNING_KEYS):
            got = sorted(running) if isinstance(running, Mapping) else type(running).__name__
            raise ValueError(f"{owner}: 'running_episodes' must be a dict of {list(_RUNNING_KEYS)}, got {got}")
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
        return dict(running)

    def _load_running_episodes(self, running: Mapping[str, Any]) -> None:
        """Put the (checked) running episodes of :meth:`_running_episodes` into the ``MjData`` and the buffers."""
        model = self.model
        integration = running["integration_state"].cpu().numpy()
        counters = running["warnings"].cpu().numpy()
        for i, data in enumerate(self.datas):
            mujoco.mj_setState(model, data, integration[i], _INTEGRATION_STATE)
            self._forward(data)  # the derived quantities of the state (the next step recomputes them anyway)
            for warning, number in zip(data.warning, counters[i], strict=True):
                warning.number = int(number)
        self._time = running["time"].cpu().numpy().copy()
        self._previous_position = running["previous_position"].cpu().numpy().copy()
        gathered = [self._state, *(buffer for _, _, buffer in self._readers)]
        for array, values in zip(gathered, running["gathered"], strict=True):
            array[:] = values.cpu().numpy()

    # ------------------------------------------------------------------ copies and pickles
    def __getstate__(self) -> dict[str, Any]:
        """The env's state without its threads, with each ``MjData`` and buffer as in the running episodes."""
        state = dict(super().__getstate__())
        for key in _REBUILT:
            state.pop(key, None)
        if self.__dict__.get("datas") is not None:
            state["_saved_running_episodes"] = self._running_episodes()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        running = state.pop("_saved_running_episodes", None)
        super().__setstate__(state)
        self._pool = None
        if running is None:  # pickled before __init__ had built the simulation
            return
        self.datas = [mujoco.MjData(self.model) for _ in range(self.num_envs)]
        self._setup_buffers()
        self._load_running_episodes(running)
        if not self._closed:
            self._start_threads()

    # ------------------------------------------------------------------ lifetime
    def close(self, *, raise_if_closed: bool = True) -> None:
        """Stop the threads; stepping or resetting afterwards raises a ``RuntimeError``. Closing twice is allowed."""
        pool = self.__dict__.get("_pool")
        if pool is not None:
            pool.shutdown(wait=True)
            self._pool = None
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
