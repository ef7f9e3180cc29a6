"""Frames/s of BatchedMujocoEnv against the bare MuJoCo physics in the same process, and against its peers.

``python benchmarks/batched_mujoco.py [--cases HalfCheetah-v5:16,64 Hopper-v5:64] [--repeats 3]
[--skip PEER ...] [--preset-envs 16] [--preset-frames 3200] [--output runs/batched_mujoco] [--tiny]``

For every case (env id × number of envs) and repeat, these measurements run back to back, so each
ratio compares numbers taken under the same machine load:

- ``floor_threads``: the bare physics: ``ctrl = action`` and ``mujoco.mj_step(model, data,
  nstep=frame_skip)`` for every env, split into contiguous chunks over ``num_threads`` threads (the
  calling thread and a ``ThreadPoolExecutor``), nothing else.
- ``floor_rollout``: ``mujoco.rollout.Rollout(nthread=num_threads).rollout`` of ``frame_skip``
  substeps from the ``mjSTATE_FULLPHYSICS`` states of all envs per step (best of two chunk sizes).
- ``floor_batch``: ``mujoco.batch.Batch.step(nstep=frame_skip)`` of all envs per step (the env's own
  batch, ``num_threads`` threads) after writing the precomputed controls into its bound ``ctrl`` rows.
  The floor is the fastest of the three.
- ``env``: the Collector below over ``BatchedMujocoEnv(env_id, N)`` alone (no transforms): the env and TorchRL's
  per-step machinery.
- ``collector`` (the pipeline): a ``torchrl.collectors.Collector`` with uniform random actions
  (``torchtasks.bench.collector.UniformActions``, the policy of every Collector column) and one torch
  thread over the preset users build, ``gymnasium_env(env_id, num_envs=N, backend="batched")``
  (BatchedMujocoEnv, StepCounter(1000), the locomotion task's TaskTransform, ZeroBrokenStepReward,
  RewardSum), the first batch not timed.

and the peers (each can be left out with ``--skip``; one that cannot be imported is reported as
"not installed" instead of measured):

- ``gym_vector``: the same Collector over ``GymWrapper(gymnasium.make_vec(env_id, num_envs,
  vectorization_mode="sync", vector_kwargs={"autoreset_mode": AutoresetMode.DISABLED}))`` (TorchRL
  prefers DISABLED: the collector resets the done envs through ``reset(options={"reset_mask": ...})``)
  with ``StepCounter(1000)`` and ``RewardSum()``, no task. Gymnasium steps the envs one after the
  other in the calling thread.
- ``envpool_raw``: envpool's own ``step`` (``envpool.make(env_id, env_type="gymnasium", num_envs=N,
  batch_size=N, num_threads=num_threads)``, synchronous: all envs every step), random actions drawn
  beforehand, no TorchRL. envpool 1.2.5 has the v5 ids; it steps its own, statically linked MuJoCo
  (3.6), not the ``mujoco`` package the floor uses, and resets finished episodes by itself (the step
  after the end of an episode is a reset).
- ``envpool_collector``: the Collector over TorchRL's ``MultiThreadedEnv(N, env_id,
  create_env_kwargs={"num_threads": num_threads})`` (envpool inside) with ``StepCounter(1000)`` and
  ``RewardSum()``, no task. TorchRL 0.14 needs ``gym`` (0.26) and ``treevalue`` for it, and builds its
  specs under the gym backend while envpool 1.2.5 returns Gymnasium spaces, so this benchmark registers
  Gymnasium's ``Box`` in ``torchrl.envs.libs.gym._conversion_registry`` first.

Once per env id (not per case), the current preset ``preset``: a Collector over
``torchtasks.envs.locomotion.gymnasium_env(env_id, num_envs=--preset-envs, backend="gymnasium")`` (a
``ParallelEnv`` of spawned Gymnasium workers + StepCounter + TaskTransform + RewardSum), timed over
``--preset-frames`` frames after a first, untimed batch (the start-up time is recorded too). Every row
of the env id divides its pipeline's frames/s by it.

envpool, gym and treevalue are not dependencies of torchtasks; ``make bench-venv`` makes ``.venv-bench``
with them (see benchmarks/README.md).

The physics floors start from Gymnasium's reset distribution and never reset (a Hopper that fell
keeps lying), the env and collectors reset episodes as TorchRL asks, so for envs that terminate the
physics mix differs a little. The table reports medians over the repeats; a ratio is the median of
the per-repeat ratios to that repeat's floor. Results go to ``<output>/results.json`` (all raw
numbers, the CPU seconds this process got per second of each measurement, the machine's load average
before and after: other processes on the machine slow the threads down) and ``<output>/results.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import shlex
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch
from mujoco import rollout as mujoco_rollout
from torchrl.collectors import Collector
from torchrl.envs import Compose, EnvBase, RewardSum, StepCounter, TransformedEnv

from torchtasks.bench.collector import uniform_policy
from torchtasks.envs import BatchedMujocoEnv, gymnasium_env

DEFAULT_CASES = [
    "HalfCheetah-v5:16,64,256",
    "Hopper-v5:64,256",
    "Walker2d-v5:64,256",
    "Ant-v5:64,256",
    "Humanoid-v5:64,256",
]
#: frames per measurement (at least MIN_STEPS steps): about a second of physics for each case
FRAMES = {"HalfCheetah-v5": 60_000, "Hopper-v5": 30_000, "Walker2d-v5": 30_000, "Ant-v5": 12_000, "Humanoid-v5": 5_000}
MIN_STEPS = 60
VARIANTS = ("floor_threads", "floor_rollout", "floor_batch", "env", "collector")
#: the bare-physics variants, and the name each gives the floor when it is the fastest
FLOORS = {"floor_threads": "threads", "floor_rollout": "rollout", "floor_batch": "batch"}
#: measured in every repeat of every case, when installed and not skipped
PEERS = ("gym_vector", "envpool_raw", "envpool_collector")
#: the ParallelEnv preset: once per env id
PRESET = "preset"
#: the Python modules each peer needs (beyond this benchmark's own imports)
PEER_MODULES = {
    "gym_vector": ("gymnasium",),
    "envpool_raw": ("envpool",),
    "envpool_collector": ("envpool", "gym", "treevalue"),
}


def _parse_cases(specs: list[str]) -> list[tuple[str, int]]:
    cases = []
    for spec in specs:
        env_id, _, sizes = spec.partition(":")
        if not sizes:
            raise SystemExit(f"a case is ENV_ID:N[,N...], got {spec!r}")
        cases.extend((env_id, int(size)) for size in sizes.split(","))
    return cases


def _fresh_env(env_id: str, num_envs: int, num_threads: int) -> BatchedMujocoEnv:
    env = BatchedMujocoEnv(env_id, num_envs, seed=0, num_threads=num_threads)
    env.reset()
    return env


def floor_threads(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of ``ctrl = action`` + ``mj_step(nstep=frame_skip)`` over ``num_threads`` threads."""
    env = _fresh_env(env_id, num_envs, num_threads)
    model, nstep = env.model, env.frame_skip
    datas = [env.batch.get_data(i) for i in range(num_envs)]
    low, high = model.actuator_ctrlrange.T
    actions = np.random.default_rng(0).uniform(low, high, size=(steps, num_envs, model.nu))
    chunks = [(int(c[0]), int(c[-1]) + 1) for c in np.array_split(np.arange(num_envs), num_threads)]
    pool = ThreadPoolExecutor(num_threads - 1) if num_threads > 1 else None

    def advance(start: int, stop: int, action: np.ndarray) -> None:
        for i in range(start, stop):
            data = datas[i]
            data.ctrl[:] = action[i]
            mujoco.mj_step(model, data, nstep)

    started = time.perf_counter()
    for action in actions:
        futures = [pool.submit(advance, start, stop, action) for start, stop in chunks[1:]] if pool else []
        advance(*chunks[0], action)
        for future in futures:
            future.result()
    elapsed = time.perf_counter() - started
    if pool is not None:
        pool.shutdown()
    env.close()
    return num_envs * steps / elapsed


def floor_rollout(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of ``mujoco.rollout`` stepping all envs ``frame_skip`` substeps per step (best of two chunk sizes)."""
    env = _fresh_env(env_id, num_envs, num_threads)
    model, nstep = env.model, env.frame_skip
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    size = mujoco.mj_stateSize(model, spec)
    initial = np.empty((num_envs, size))
    for i in range(num_envs):
        mujoco.mj_getState(model, env.batch.get_data(i), initial[i], spec)
    low, high = model.actuator_ctrlrange.T
    actions = np.random.default_rng(0).uniform(low, high, size=(steps, num_envs, 1, model.nu))
    controls = np.ascontiguousarray(np.broadcast_to(actions, (steps, num_envs, nstep, model.nu)))
    models = [model] * num_envs
    scratch = [mujoco.MjData(model) for _ in range(num_threads)]
    out = np.empty((num_envs, nstep, size))
    sensors = np.empty((num_envs, nstep, model.nsensordata))
    best = 0.0
    with mujoco_rollout.Rollout(nthread=num_threads if num_threads > 1 else 0) as runner:
        for chunk_size in (None, max(1, num_envs // max(num_threads, 1))):
            state = initial.copy()
            started = time.perf_counter()
            for control in controls:
                runner.rollout(
                    models, scratch, state, control, nstep=nstep, state=out, sensordata=sensors,
                    skip_checks=True, chunk_size=chunk_size,
                )  # fmt: skip
                state[:] = out[:, -1]
            best = max(best, num_envs * steps / (time.perf_counter() - started))
    env.close()
    return best


def floor_batch(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of ``ctrl = action`` + ``Batch.step(nstep=frame_skip)`` (the env's batch, ``num_threads`` threads)."""
    env = _fresh_env(env_id, num_envs, num_threads)
    batch, model, nstep = env.batch, env.model, env.frame_skip
    low, high = model.actuator_ctrlrange.T
    actions = np.random.default_rng(0).uniform(low, high, size=(steps, num_envs, model.nu))
    ctrl = batch.bind("ctrl")
    started = time.perf_counter()
    for action in actions:
        ctrl[:] = action
        batch.step(None, nstep)
    elapsed = time.perf_counter() - started
    env.close()
    return num_envs * steps / elapsed


def env_collector(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of a Collector (random policy, one torch thread) over BatchedMujocoEnv alone; first batch untimed."""
    return _collector_frames_per_second(
        lambda: BatchedMujocoEnv(env_id, num_envs, seed=0, num_threads=num_threads), num_envs, steps
    )


def make_task_env(env_id: str, num_envs: int, num_threads: int) -> TransformedEnv:
    """The measured pipeline, as users build it: ``gymnasium_env(env_id, num_envs, backend="batched")``
    (the batched env, StepCounter(1000), the locomotion task, ZeroBrokenStepReward, RewardSum)."""
    return gymnasium_env(env_id, num_envs=num_envs, seed=0, backend="batched", num_threads=num_threads)


def endless_collector(env: EnvBase, frames_per_batch: int) -> Collector:
    """A Collector over ``env`` with :func:`uniform_policy`, endless (``total_frames=-1``): stopped by hand.

    A collector that reaches ``total_frames`` closes the env before it returns the last batch, which
    would time the env's close (seconds for a ParallelEnv).
    """
    return Collector(
        env,
        policy=uniform_policy(env),
        frames_per_batch=frames_per_batch,
        total_frames=-1,
        auto_register_policy_transforms=False,
    )


def _timed_batches(iterator: Any, batches: int) -> tuple[int, float]:
    """Draw ``batches`` batches from a collector's iterator: ``(frames, seconds)``."""
    frames = 0
    started = time.perf_counter()
    for _ in range(batches):
        frames += next(iterator).numel()
    return frames, time.perf_counter() - started


def _collector_frames_per_second(make_env: Callable[[], EnvBase], num_envs: int, steps: int) -> float:
    """Frames/s of a Collector (uniform random actions, one torch thread) over ``make_env()``; first batch untimed."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        steps_per_batch = max(1, min(steps, 100))
        batches = max(1, steps // steps_per_batch)
        frames_per_batch = num_envs * steps_per_batch
        data_collector = endless_collector(make_env(), frames_per_batch)
        iterator = iter(data_collector)
        next(iterator)
        frames, elapsed = _timed_batches(iterator, batches)
        data_collector.shutdown()
    finally:
        torch.set_num_threads(threads)
    return frames / elapsed


def collector(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of a Collector (random policy, one torch thread) over :func:`make_task_env`; first batch untimed."""
    return _collector_frames_per_second(lambda: make_task_env(env_id, num_envs, num_threads), num_envs, steps)


def _counted(env: EnvBase) -> TransformedEnv:
    """The peers' pipeline: the env, StepCounter(1000) and RewardSum, no task."""
    return TransformedEnv(env, Compose(StepCounter(1000), RewardSum()))


def gym_vector_collector(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of the Collector over GymWrapper(make_vec(sync, autoreset disabled)) + StepCounter + RewardSum."""
    import gymnasium as gym
    from torchrl.envs import GymWrapper

    def make_env() -> EnvBase:
        vector = gym.make_vec(
            env_id,
            num_envs=num_envs,
            vectorization_mode="sync",
            vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.DISABLED},
        )
        return _counted(GymWrapper(vector))

    return _collector_frames_per_second(make_env, num_envs, steps)


def envpool_raw(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of envpool's synchronous ``step`` over all envs with ``num_threads`` threads (random actions)."""
    import envpool

    pool = envpool.make(
        env_id, env_type="gymnasium", num_envs=num_envs, batch_size=num_envs, num_threads=num_threads, seed=0
    )
    space = pool.action_space
    shape = (steps + 3, num_envs, *space.shape)
    actions = np.random.default_rng(0).uniform(space.low, space.high, size=shape).astype(space.dtype)
    pool.reset()
    for action in actions[:3]:
        pool.step(action)
    started = time.perf_counter()
    for action in actions[3:]:
        pool.step(action)
    elapsed = time.perf_counter() - started
    pool.close()
    return num_envs * steps / elapsed


def _register_gymnasium_box() -> None:
    """TorchRL 0.14 converts envpool's spaces under the gym backend; envpool 1.2.5 returns Gymnasium's Box."""
    import gymnasium
    from torchrl.envs.libs import gym as torchrl_gym

    # not setdefault: under the default (gymnasium) backend the registry's lookup finds Box by name and inserts nothing
    if gymnasium.spaces.Box not in torchrl_gym._conversion_registry:
        torchrl_gym._conversion_registry[gymnasium.spaces.Box] = torchrl_gym.convert_box_spec


def envpool_collector(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of the Collector over TorchRL's MultiThreadedEnv (envpool) + StepCounter + RewardSum."""
    from torchrl.envs import MultiThreadedEnv

    # treevalue 1.5 (imported by TorchRL's envpool wrapper) registers its trees with a deprecated torch call
    warnings.filterwarnings("ignore", category=FutureWarning, module=r"treevalue\.")
    _register_gymnasium_box()

    def make_env() -> EnvBase:
        kwargs = {"num_threads": num_threads, "seed": 0}
        return _counted(MultiThreadedEnv(num_envs, env_id, create_env_kwargs=kwargs))

    return _collector_frames_per_second(make_env, num_envs, steps)


def preset_collector(env_id: str, num_envs: int, frames: int) -> dict[str, float]:
    """Frames/s of a Collector (one torch thread) over today's ParallelEnv preset, and its start-up seconds.

    ``gymnasium_env(env_id, num_envs=num_envs, backend="gymnasium")``: a ParallelEnv of spawned
    Gymnasium workers with StepCounter, the task's TaskTransform and RewardSum. The first batch
    (``num_envs * 50`` frames, fewer when ``frames`` is small) is not timed; the start-up time is
    from building the env to the end of that batch.
    """
    from torchtasks.envs.locomotion import gymnasium_env

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        steps_per_batch = max(1, min(50, frames // num_envs))
        frames_per_batch = num_envs * steps_per_batch
        batches = max(1, math.ceil(frames / frames_per_batch))
        started = time.perf_counter()
        env = gymnasium_env(env_id, num_envs=num_envs, backend="gymnasium", seed=0)
        data_collector = endless_collector(env, frames_per_batch)
        iterator = iter(data_collector)
        next(iterator)
        startup = time.perf_counter() - started
        counted, elapsed = _timed_batches(iterator, batches)
        data_collector.shutdown()
    finally:
        torch.set_num_threads(threads)
    return {"frames_per_second": counted / elapsed, "frames": counted, "seconds": elapsed, "startup_seconds": startup}


def peer_status(variant: str) -> str | None:
    """Why ``variant`` cannot run here ("not installed (module, ...)"), or None when it can."""
    missing = [name for name in PEER_MODULES.get(variant, ()) if importlib.util.find_spec(name) is None]
    return f"not installed ({', '.join(missing)})" if missing else None


MEASURES = {
    "floor_threads": floor_threads,
    "floor_rollout": floor_rollout,
    "floor_batch": floor_batch,
    "env": env_collector,
    "collector": collector,
    "gym_vector": gym_vector_collector,
    "envpool_raw": envpool_raw,
    "envpool_collector": envpool_collector,
}


def run(
    cases: list[tuple[str, int]],
    repeats: int,
    num_threads: int,
    frames: int | None = None,
    skip: tuple[str, ...] = (),
    preset_envs: int = 16,
    preset_frames: int = 3_200,
    preset_ids: set[str] | None = None,
) -> tuple[list[dict[str, Any]], dict[str, dict[str, Any]]]:
    """Measure every case; return the rows and the preset measurement of each env id.

    ``preset_ids``: the env ids whose preset is measured (default: all of them); the others say "skipped".
    """
    status: dict[str, str | None] = {
        variant: "skipped" if variant in skip else peer_status(variant) for variant in (*PEERS, PRESET)
    }
    peers = [variant for variant in PEERS if status[variant] is None]
    presets: dict[str, dict[str, Any]] = {}
    rows = []
    for env_id, num_envs in cases:
        if env_id not in presets:
            if status[PRESET] is None and (preset_ids is None or env_id in preset_ids):
                presets[env_id] = {"num_envs": preset_envs, **preset_collector(env_id, preset_envs, preset_frames)}
                print(
                    f"{env_id}: ParallelEnv preset ({preset_envs} envs): "
                    f"{presets[env_id]['frames_per_second']:,.0f} frames/s over {presets[env_id]['frames']} frames "
                    f"(start-up {presets[env_id]['startup_seconds']:.1f} s)",
                    flush=True,
                )
            else:
                presets[env_id] = {"status": status[PRESET] or "not measured (--tiny: first env id only)"}
        target = FRAMES.get(env_id, 20_000) if frames is None else frames
        steps = max(MIN_STEPS if frames is None else 1, target // num_envs)
        measured = [*VARIANTS, *peers]
        raw: dict[str, list[float]] = {variant: [] for variant in measured}
        cpu_share: dict[str, list[float]] = {variant: [] for variant in measured}
        for _ in range(repeats):
            for variant in measured:
                cpu, wall = time.process_time(), time.perf_counter()
                raw[variant].append(MEASURES[variant](env_id, num_envs, steps, num_threads))
                cpu_share[variant].append((time.process_time() - cpu) / (time.perf_counter() - wall))
        fastest = [max(FLOORS, key=lambda variant, k=k: raw[variant][k]) for k in range(repeats)]
        floors = [raw[variant][k] for k, variant in enumerate(fastest)]
        row: dict[str, Any] = {
            "env": env_id,
            "num_envs": num_envs,
            "steps": steps,
            "raw": raw,
            "floor": floors,
            "floor_source": [FLOORS[variant] for variant in fastest],
            "cpu_seconds_per_second": cpu_share,
            "peer_status": {variant: status[variant] for variant in PEERS},
            "preset": presets[env_id],
        }
        for variant in (*VARIANTS, *PEERS):
            row[f"{variant}_median"] = statistics.median(raw[variant]) if variant in raw else None
        row["floor_median"] = statistics.median(floors)
        for variant in ("env", "collector", *PEERS):
            if variant in raw:
                ratios = [value / floor for value, floor in zip(raw[variant], floors, strict=True)]
                row[f"{variant}_ratio_median"] = statistics.median(ratios)
            else:
                row[f"{variant}_ratio_median"] = None
        preset_fps = presets[env_id].get("frames_per_second")
        row["preset_median"] = preset_fps
        row["collector_over_preset"] = row["collector_median"] / preset_fps if preset_fps else None
        rows.append(row)
        print(_format_row(row), flush=True)
    return rows, presets


def header(num_threads: int, preset_envs: int) -> str:
    """The Markdown table's header: frames/s in every cell, the ratio named by the column in brackets."""
    columns = [
        "env",
        "envs",
        "physics floor (which)",
        "BatchedMujocoEnv alone (÷ floor)",
        "pipeline (÷ floor)",
        f"ParallelEnv preset, {preset_envs} envs (pipeline ÷ preset)",
        "GymWrapper sync-vector collector (÷ floor)",
        f"envpool raw step, {num_threads} threads (÷ floor)",
        "MultiThreadedEnv collector (÷ floor)",
    ]
    return "| " + " | ".join(columns) + " |\n" + "|---" * len(columns) + "|"


def legend(num_threads: int, preset_envs: int) -> str:
    """What each column of :func:`header` measures."""
    return "\n".join(
        [
            f"- physics floor: the fastest of `mujoco.mj_step(nstep=frame_skip)` over {num_threads} threads, "
            f"`mujoco.rollout` and `mujoco.batch.Batch.step` with {num_threads} threads (the `mujoco` package's "
            "MuJoCo, no TorchRL; the bracket names it), measured in "
            "the same repeat as the row's other columns; every ratio to the floor divides by the floor of its "
            "own repeat (the median ratio is shown).",
            f"- BatchedMujocoEnv alone: the pipeline's `Collector` over `BatchedMujocoEnv(env_id, N, "
            f"num_threads={num_threads})`, no transforms.",
            "- pipeline: a `Collector` (uniform random actions, one torch thread) over the preset users build, "
            '`gymnasium_env(env_id, num_envs=N, backend="batched")`: BatchedMujocoEnv + `StepCounter(1000)` + '
            "`TaskTransform(locomotion_task(env_id))` + `ZeroBrokenStepReward` + `RewardSum()`.",
            f"- ParallelEnv preset: the same Collector over `gymnasium_env(env_id, num_envs={preset_envs}, "
            f'backend="gymnasium")` (a ParallelEnv of {preset_envs} spawned Gymnasium workers + StepCounter + '
            "TaskTransform + RewardSum), measured once per env id; the bracket is the row's pipeline frames/s "
            "divided by it.",
            "- GymWrapper sync-vector collector: the Collector over `GymWrapper(gymnasium.make_vec(env_id, N, "
            'vectorization_mode="sync", vector_kwargs={"autoreset_mode": AutoresetMode.DISABLED}))` + StepCounter + '
            "RewardSum, no task (Gymnasium steps the envs one by one in one thread).",
            f'- envpool raw step: `envpool.make(env_id, env_type="gymnasium", num_envs=N, batch_size=N, '
            f"num_threads={num_threads}).step(actions)`, no TorchRL; envpool steps its own statically linked MuJoCo "
            "(3.6), not the floor's.",
            f"- MultiThreadedEnv collector: the Collector over TorchRL's `MultiThreadedEnv(N, env_id, "
            f'create_env_kwargs={{"num_threads": {num_threads}}})` (envpool) + StepCounter + RewardSum, no task.',
        ]
    )


def _cell(row: dict[str, Any], variant: str) -> str:
    value = row[f"{variant}_median"]
    if value is None:
        return row["peer_status"][variant] or "n/a"
    return f"{value:,.0f} ({row[f'{variant}_ratio_median']:.2f})"


def _format_row(row: dict[str, Any]) -> str:
    sources = set(row["floor_source"])
    source = sources.pop() if len(sources) == 1 else "mixed"
    if row["preset_median"] is None:
        preset = row["preset"].get("status", "skipped")
    else:
        preset = f"{row['preset_median']:,.0f} (×{row['collector_over_preset']:.1f})"
    cells = [
        row["env"],
        str(row["num_envs"]),
        f"{row['floor_median']:,.0f} ({source})",
        _cell(row, "env"),
        _cell(row, "collector"),
        preset,
        *(_cell(row, variant) for variant in PEERS),
    ]
    return "| " + " | ".join(cells) + " |"


FLOORS_HEADER = "| case | floor: threaded mj_step | floor: mujoco.rollout | floor: mujoco.batch |\n|---|---|---|---|"


def _format_floors(row: dict[str, Any]) -> str:
    return (
        f"| {row['env']} × {row['num_envs']} | {row['floor_threads_median']:,.0f} "
        f"| {row['floor_rollout_median']:,.0f} | {row['floor_batch_median']:,.0f} |"
    )


def _versions() -> dict[str, str | None]:
    from importlib.metadata import PackageNotFoundError, version

    found: dict[str, str | None] = {}
    for name in ("torch", "torchrl", "tensordict", "numpy", "mujoco", "gymnasium", "envpool", "gym", "treevalue"):
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = None
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="ENV_ID:N[,N...] (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="threads (default: the CPUs of this process)")
    parser.add_argument(
        "--skip", nargs="+", default=[], choices=[*PEERS, PRESET], help="peers not to measure (default: none)"
    )
    parser.add_argument("--preset-envs", type=int, default=16, help="envs of the ParallelEnv preset (%(default)s)")
    parser.add_argument(
        "--preset-frames", type=int, default=3_200, help="timed frames of the preset, per env id (%(default)s)"
    )
    parser.add_argument("--output", type=Path, default=Path("runs/batched_mujoco"))
    parser.add_argument("--tiny", action="store_true", help="every code path with tiny sizes (timings mean nothing)")
    args = parser.parse_args(argv)
    num_threads = args.threads or len(os.sched_getaffinity(0))
    cases = _parse_cases(["Hopper-v5:2", "Ant-v5:3"] if args.tiny else args.cases)
    repeats = 1 if args.tiny else args.repeats
    preset_envs = 2 if args.tiny else args.preset_envs
    preset_frames = 8 if args.tiny else args.preset_frames
    # --tiny spawns the preset's workers for the first env id only (a few seconds each)
    preset_ids = {cases[0][0]} if args.tiny else None
    load_before = os.getloadavg()
    print(f"frames/s, {num_threads} threads, load average {load_before[0]:.2f}; ratios in brackets")
    table_header = header(num_threads, preset_envs)
    print(table_header, flush=True)
    rows, presets = run(
        cases,
        repeats,
        num_threads,
        frames=8 if args.tiny else None,
        skip=tuple(args.skip),
        preset_envs=preset_envs,
        preset_frames=preset_frames,
        preset_ids=preset_ids,
    )
    load_after = os.getloadavg()
    args.output.mkdir(parents=True, exist_ok=True)
    meta = {
        "python": sys.version.split()[0],
        "versions": _versions(),
        "torch": torch.__version__,
        "mujoco": mujoco.__version__,
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "threads": num_threads,
        "torch_threads_in_collectors": 1,
        "repeats": repeats,
        "tiny": args.tiny,
        "preset_envs": preset_envs,
        "preset_frames": preset_frames,
        "load_average_before": load_before,
        "load_average_after": load_after,
        "time": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": shlex.join(["python", "benchmarks/batched_mujoco.py", *(sys.argv[1:] if argv is None else argv)]),
    }
    (args.output / "results.json").write_text(
        json.dumps({"meta": meta, "presets": presets, "rows": rows}, indent=2) + "\n"
    )
    table = "\n".join([table_header, *(_format_row(row) for row in rows)])
    floors = "\n".join([FLOORS_HEADER, *(_format_floors(row) for row in rows)])
    versions = ", ".join(f"{name} {found or 'not installed'}" for name, found in meta["versions"].items())
    (args.output / "results.md").write_text(
        f"frames/s ({num_threads} threads, one torch thread in the collectors, medians of {repeats} repeats; "
        f"{meta['time']}, 1-minute load average {load_before[0]:.2f} before, {load_after[0]:.2f} after; "
        f"`{meta['command']}`; {versions})\n\n"
        f"{table}\n\n{legend(num_threads, preset_envs)}\n\n"
        f"The floors' three measurements (the fastest is the floor):\n\n{floors}\n"
    )
    print(f"load average after: {load_after[0]:.2f}; results in {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
