"""Frames/s of BatchedMujocoEnv against the bare MuJoCo physics in the same process.

``python benchmarks/batched_mujoco.py [--cases HalfCheetah-v5:16,64 Hopper-v5:64] [--repeats 3]
[--output runs/batched_mujoco] [--tiny]``

For every case (env id × number of envs) and repeat, four measurements run back to back, so each
ratio compares numbers taken under the same machine load:

- ``floor_threads``: the bare physics: ``ctrl = action`` and ``mujoco.mj_step(model, data,
  nstep=frame_skip)`` for every env, split into contiguous chunks over ``num_threads`` threads (the
  calling thread and a ``ThreadPoolExecutor``), nothing else.
- ``floor_rollout``: ``mujoco.rollout.Rollout(nthread=num_threads).rollout`` of ``frame_skip``
  substeps from the ``mjSTATE_FULLPHYSICS`` states of all envs per step (best of two chunk sizes).
  The floor is the faster of the two.
- ``env``: ``BatchedMujocoEnv(...).rollout(steps, break_when_any_done=False)`` (random actions).
- ``collector``: a ``torchrl.collectors.Collector`` with ``policy=None`` (random actions) and one
  torch thread over ``TransformedEnv(BatchedMujocoEnv(...), Compose(StepCounter(1000),
  TaskTransform(locomotion_task(env_id), state_key=...), RewardSum()))``, the first batch not timed.

The physics floors start from Gymnasium's reset distribution and never reset (a Hopper that fell
keeps lying), the env and collector reset episodes as TorchRL asks, so for envs that terminate the
physics mix differs a little. The table reports medians over the repeats; the ratio is the median of
the per-repeat ratios to that repeat's floor. Results go to ``<output>/results.json`` (all raw
numbers, the CPU seconds this process got per second of each measurement, the machine's load average
before and after: other processes on the machine slow the threads down) and ``<output>/results.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch
from mujoco import rollout as mujoco_rollout
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import BatchedMujocoEnv
from torchtasks.envs.locomotion import locomotion_state_layout, locomotion_task
from torchtasks.transforms import TaskTransform

DEFAULT_CASES = ["HalfCheetah-v5:16,64,256", "Hopper-v5:16,64,256", "Ant-v5:64", "Humanoid-v5:64"]
#: frames per measurement (at least MIN_STEPS steps): about a second of physics for each case
FRAMES = {"HalfCheetah-v5": 60_000, "Hopper-v5": 30_000, "Ant-v5": 12_000, "Humanoid-v5": 5_000}
MIN_STEPS = 60
VARIANTS = ("floor_threads", "floor_rollout", "env", "collector")


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
    model, datas, nstep = env.model, env.datas, env.frame_skip
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
    for i, data in enumerate(env.datas):
        mujoco.mj_getState(model, data, initial[i], spec)
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


def env_rollout(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of ``BatchedMujocoEnv.rollout`` with random actions (TorchRL's rollout loop)."""
    env = BatchedMujocoEnv(env_id, num_envs, seed=0, num_threads=num_threads)
    env.rollout(3, break_when_any_done=False)
    started = time.perf_counter()
    env.rollout(steps, break_when_any_done=False)
    elapsed = time.perf_counter() - started
    env.close()
    return num_envs * steps / elapsed


def make_task_env(env_id: str, num_envs: int, num_threads: int) -> TransformedEnv:
    """The measured pipeline: the batched env, StepCounter(1000), the locomotion task, RewardSum."""
    base = BatchedMujocoEnv(env_id, num_envs, seed=0, num_threads=num_threads)
    task = TaskTransform(locomotion_task(env_id), state_key=list(locomotion_state_layout(env_id)))
    return TransformedEnv(base, Compose(StepCounter(1000), task, RewardSum()))


def collector(env_id: str, num_envs: int, steps: int, num_threads: int) -> float:
    """Frames/s of a Collector (random policy, one torch thread) over :func:`make_task_env`; first batch untimed."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        steps_per_batch = max(1, min(steps, 100))
        batches = max(1, steps // steps_per_batch)
        frames_per_batch = num_envs * steps_per_batch
        data_collector = Collector(
            make_task_env(env_id, num_envs, num_threads),
            policy=None,
            frames_per_batch=frames_per_batch,
            total_frames=frames_per_batch * (batches + 1),
        )
        iterator = iter(data_collector)
        next(iterator)
        frames = 0
        started = time.perf_counter()
        for batch in iterator:
            frames += batch.numel()
        elapsed = time.perf_counter() - started
        data_collector.shutdown()
    finally:
        torch.set_num_threads(threads)
    return frames / elapsed


MEASURES = {"floor_threads": floor_threads, "floor_rollout": floor_rollout, "env": env_rollout, "collector": collector}


def run(
    cases: list[tuple[str, int]], repeats: int, num_threads: int, frames: int | None = None
) -> list[dict[str, Any]]:
    rows = []
    for env_id, num_envs in cases:
        target = FRAMES.get(env_id, 20_000) if frames is None else frames
        steps = max(MIN_STEPS if frames is None else 1, target // num_envs)
        raw: dict[str, list[float]] = {variant: [] for variant in VARIANTS}
        cpu_share: dict[str, list[float]] = {variant: [] for variant in VARIANTS}
        for _ in range(repeats):
            for variant in VARIANTS:
                cpu, wall = time.process_time(), time.perf_counter()
                raw[variant].append(MEASURES[variant](env_id, num_envs, steps, num_threads))
                cpu_share[variant].append((time.process_time() - cpu) / (time.perf_counter() - wall))
        floors = [max(a, b) for a, b in zip(raw["floor_threads"], raw["floor_rollout"], strict=True)]
        row: dict[str, Any] = {
            "env": env_id,
            "num_envs": num_envs,
            "steps": steps,
            "raw": raw,
            "floor": floors,
            "cpu_seconds_per_second": cpu_share,
        }
        for variant in VARIANTS:
            row[f"{variant}_median"] = statistics.median(raw[variant])
        row["floor_median"] = statistics.median(floors)
        for variant in ("env", "collector"):
            ratios = [value / floor for value, floor in zip(raw[variant], floors, strict=True)]
            row[f"{variant}_ratio_median"] = statistics.median(ratios)
        rows.append(row)
        print(_format_row(row), flush=True)
    return rows


HEADER = (
    "| env | envs | floor: threads mj_step | floor: mujoco.rollout | floor (faster) | BatchedMujocoEnv.rollout "
    "(ratio) | Collector + StepCounter + task + RewardSum (ratio) |\n|---|---|---|---|---|---|---|"
)


def _format_row(row: dict[str, Any]) -> str:
    return (
        f"| {row['env']} | {row['num_envs']} | {row['floor_threads_median']:,.0f} | {row['floor_rollout_median']:,.0f} "
        f"| {row['floor_median']:,.0f} | {row['env_median']:,.0f} ({row['env_ratio_median']:.2f}) "
        f"| {row['collector_median']:,.0f} ({row['collector_ratio_median']:.2f}) |"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES, help="ENV_ID:N[,N...] (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="threads (default: the CPUs of this process)")
    parser.add_argument("--output", type=Path, default=Path("runs/batched_mujoco"))
    parser.add_argument("--tiny", action="store_true", help="every code path with tiny sizes (timings mean nothing)")
    args = parser.parse_args(argv)
    num_threads = args.threads or len(os.sched_getaffinity(0))
    cases = _parse_cases(["Hopper-v5:2", "Ant-v5:3"] if args.tiny else args.cases)
    repeats = 1 if args.tiny else args.repeats
    load_before = os.getloadavg()
    print(f"frames/s, {num_threads} threads, load average {load_before[0]:.2f}; ratios to the floor in brackets")
    print(HEADER, flush=True)
    rows = run(cases, repeats, num_threads, frames=8 if args.tiny else None)
    load_after = os.getloadavg()
    args.output.mkdir(parents=True, exist_ok=True)
    meta = {
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "mujoco": mujoco.__version__,
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "threads": num_threads,
        "repeats": repeats,
        "load_average_before": load_before,
        "load_average_after": load_after,
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    (args.output / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2) + "\n")
    table = "\n".join([HEADER, *(_format_row(row) for row in rows)])
    (args.output / "results.md").write_text(
        f"frames/s ({num_threads} threads, load average {load_before[0]:.2f} → {load_after[0]:.2f}, "
        f"{meta['time']})\n\n{table}\n"
    )
    print(f"load average after: {load_after[0]:.2f}; results in {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
