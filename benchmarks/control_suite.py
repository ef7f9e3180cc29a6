"""Frames/s of the Control Suite presets against the bare physics and against TorchRL's DMControlEnv, interleaved.

``python benchmarks/control_suite.py [--tasks walker-walk ...] [--envs 64] [--repeats 5] [--seconds 1.0]
[--steps-per-batch 20] [--peers serial parallel parallel_pipes dm_control] [--peer-python PATH] [--threads N]
[--output runs/control_suite_bench] [--quick]``

For one task per domain (the 15 of :data:`DEFAULT_TASKS`) with ``--envs`` envs, these variants are built once per
task and then measured back to back in every repeat (``--seconds`` each, at least one batch), so each ratio compares
numbers taken under the same machine load:

- ``floor``: ``mujoco.batch.Batch.step(nstep=frame_skip, stage=mjSTAGE_VEL)`` of the batch of
  ``control_suite_base_env(task, N)`` (dm_control's compiled model, its control step as substeps, the persistent
  batch the env builds, ``--threads`` threads) after writing uniform random controls (drawn beforehand) into its
  bound ``ctrl`` rows: the physics alone, no reset, no reading.
- ``env``: a ``torchrl.collectors.Collector`` (uniform random actions, ``torchtasks.bench.collector.UniformActions``,
  one torch thread, ``N * --steps-per-batch`` frames per batch) over ``control_suite_base_env(task, N)`` alone: the
  env's readings (observation and task-state entries) and TorchRL's per-step machinery, no task.
- ``preset``: the same Collector over the preset users build, ``control_suite_env(task, N)`` (the env,
  ``StepCounter(1000)``, the task's ``TaskTransform``, ``ZeroBrokenStepReward``, ``RewardSum``).

and the peers, TorchRL's ``DMControlEnv(domain, task)`` (dm-control 1.0.50 on MuJoCo 3.17.0, which dm-control needs)
in the benchmark venv ``make bench-dmc-venv`` builds, run by a worker process (``benchmarks/control_suite_peer.py``;
its docstring says what each variant is): ``serial`` (the same Collector over ``SerialEnv(N, DMControlEnv)`` +
``StepCounter(1000)`` + ``RewardSum()``), ``parallel`` (``ParallelEnv(W, SerialEnv(N / W, DMControlEnv))``, W =
``--threads`` worker processes: one per core; TorchRL 0.14.1's parent process spin-polls shared-memory flags while
its workers step, so it keeps a core busy), ``parallel_pipes`` (the same with ``use_buffers=False``: the workers send
their results through pipes, which the parent blocks on), ``parallel_per_env`` (``ParallelEnv(N, DMControlEnv)``, one
process per env: not measured by default, 64 processes of ~340 MB each on this 2-core machine) and ``dm_control``
(dm_control's own ``env.step`` in a Python loop over the N envs, no TorchRL). Without the venv (``--peer-python`` or
``$TORCHTASKS_BENCH_DMC_PYTHON``, else ``.venv-bench-dmc/bin/python`` of this repository) the peer columns say why
they were not measured.

Every variant's first batch is drawn when it is built, not timed; the peers' start-up seconds are recorded. The
table reports medians over the repeats; a ratio is the median of the per-repeat ratios to that repeat's floor.
Results: ``<output>/results.json`` (every repeat's numbers, the CPU seconds each measurement got per second: this
process's threads, or the peer worker's and its workers', the load average before every task and after the run, the
versions) and ``<output>/results.md``.
``--quick`` runs every code path on one small task in seconds (its timings mean nothing).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import mujoco
import numpy as np
import torch
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, TransformedEnv

from torchtasks.bench.collector import uniform_policy
from torchtasks.envs.control_suite import CONTROL_SUITE_TASKS, control_suite_base_env, control_suite_env

#: one task per domain, in dm_control's order of domains
DEFAULT_TASKS = (
    "acrobot-swingup",
    "ball_in_cup-catch",
    "cartpole-swingup",
    "cheetah-run",
    "finger-spin",
    "fish-swim",
    "hopper-hop",
    "humanoid-walk",
    "manipulator-bring_ball",
    "pendulum-swingup",
    "point_mass-easy",
    "reacher-easy",
    "swimmer-swimmer6",
    "walker-walk",
    "quadruped-walk",
)
#: this process's variants, measured in this order in every repeat
OURS = ("floor", "env", "preset")
#: ``--breakdown``: the preset's transforms added one at a time between ``env`` and ``preset``, then the preset over an
#: env that simulates nothing; in this order
LAYERS = ("+StepCounter", "+task", "+ZeroBrokenStepReward")
NO_PHYSICS = "preset, no physics"
BREAKDOWN = (*LAYERS, NO_PHYSICS)
#: the peer variants (benchmarks/control_suite_peer.py) and those measured by default
PEERS = ("serial", "parallel", "parallel_pipes", "parallel_per_env", "dm_control")
DEFAULT_PEERS = ("serial", "parallel", "parallel_pipes", "dm_control")
#: the peers that are TorchRL envs (the speed-up of the preset is over the fastest of them)
TORCHRL_PEERS = ("serial", "parallel", "parallel_pipes", "parallel_per_env")
PEER_PYTHON_VARIABLE = "TORCHTASKS_BENCH_DMC_PYTHON"
ROOT = Path(__file__).resolve().parents[1]
PEER_SCRIPT = Path(__file__).resolve().with_name("control_suite_peer.py")
DEFAULT_PEER_PYTHON = ROOT / ".venv-bench-dmc" / "bin" / "python"


class Floor:
    """``ctrl = action`` + ``Batch.step(nstep=frame_skip, stage=mjSTAGE_VEL)`` on the batch of ``env``'s MuJoCo env.

    ``env`` is a ``BatchedMujocoEnv`` or a ``TransformedEnv`` over one (reset whole once, then only its base env's
    batch is stepped); ``steps`` uniform random actions per env in the actuators' ranges, drawn from seed 0. Closing
    the floor closes ``env``.
    """

    def __init__(self, env: EnvBase, steps: int) -> None:
        self.env = env
        self.base = env.base_env if isinstance(env, TransformedEnv) else env
        stage = self.base.declaration.stage
        if stage != "velocity":  # what the presets read, so the floor steps the same stages
            raise RuntimeError(f"Floor: the env's stage is {stage!r}, not 'velocity'")
        env.reset()
        model = self.base.model
        low, high = model.actuator_ctrlrange.T
        self.actions = np.random.default_rng(0).uniform(low, high, size=(steps, self.base.num_envs, model.nu))
        self.ctrl = self.base.batch.bind("ctrl")
        self.stage = int(mujoco.mjtStage.mjSTAGE_VEL)
        self.batch()

    def batch(self) -> int:
        batch, nstep = self.base.batch, self.base.frame_skip
        for action in self.actions:
            self.ctrl[:] = action
            batch.step(None, nstep, self.stage)
        return self.actions.shape[0] * self.actions.shape[1]

    def close(self) -> None:
        self.env.close()


class Collected:
    """An endless Collector (uniform random actions) over ``env``, its first batch drawn here; stopped by hand.

    A collector that reaches ``total_frames`` closes the env before it returns the last batch: endless, it does not.
    """

    def __init__(self, env: EnvBase, frames_per_batch: int) -> None:
        self.collector = Collector(
            env,
            policy=uniform_policy(env),
            frames_per_batch=frames_per_batch,
            total_frames=-1,
            auto_register_policy_transforms=False,
        )
        self.iterator = iter(self.collector)
        next(self.iterator)

    def batch(self) -> int:
        return next(self.iterator).numel()

    def close(self) -> None:
        self.collector.shutdown()


def measure(measured: Floor | Collected, seconds: float) -> dict[str, float]:
    """Batches of ``measured`` until ``seconds`` have passed (at least one): frames/s and this process's CPU share."""
    frames, elapsed, cpu = 0, 0.0, time.process_time()
    started = time.perf_counter()
    while elapsed < seconds or frames == 0:
        frames += measured.batch()
        elapsed = time.perf_counter() - started
    return {
        "frames_per_second": frames / elapsed,
        "cpu_seconds_per_second": (time.process_time() - cpu) / elapsed,
    }


def preset_layers(task: str, num_envs: int, num_threads: int, layers: int) -> TransformedEnv:
    """``control_suite_env(task, num_envs)`` with only its first ``layers`` transforms (4: the preset)."""
    env = control_suite_env(task, num_envs, seed=0, num_threads=num_threads)
    while len(env.transform) > layers:
        env.transform.pop()
    return env


def no_physics_preset(task: str, num_envs: int, num_threads: int) -> TransformedEnv:
    """The preset's transforms over an env with its base env's specs that simulates nothing (zeros every step)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        from pipeline_costs import NoPhysicsEnv
    finally:
        sys.path.pop(0)
    preset = control_suite_env(task, num_envs, seed=0, num_threads=num_threads)
    env = TransformedEnv(NoPhysicsEnv(preset.base_env), preset.transform.clone())
    preset.close()
    return env


def build_ours(
    task: str, num_envs: int, num_threads: int, steps: int, breakdown: bool = False
) -> dict[str, Floor | Collected]:
    """The floor, the env alone and the preset of ``task`` (and the :data:`BREAKDOWN` variants), each with its first
    batch drawn, in the order they are measured."""
    frames_per_batch = num_envs * steps
    kwargs = {"seed": 0, "num_threads": num_threads}
    makers: dict[str, Callable[[], Floor | Collected]] = {
        "floor": lambda: Floor(control_suite_base_env(task, num_envs, **kwargs), steps),
        "env": lambda: Collected(control_suite_base_env(task, num_envs, **kwargs), frames_per_batch),
    }
    if breakdown:
        for layers, variant in enumerate(LAYERS, start=1):
            makers[variant] = lambda layers=layers: Collected(
                preset_layers(task, num_envs, num_threads, layers), frames_per_batch
            )
    makers["preset"] = lambda: Collected(control_suite_env(task, num_envs, **kwargs), frames_per_batch)
    if breakdown:
        makers[NO_PHYSICS] = lambda: Collected(no_physics_preset(task, num_envs, num_threads), frames_per_batch)
    return {variant: make() for variant, make in makers.items()}


def peer_python(explicit: str | None) -> tuple[str | None, str | None]:
    """(the peer venv's python, None) or (None, why there is none)."""
    if explicit is not None:
        python, source = explicit, "--peer-python"
    elif os.environ.get(PEER_PYTHON_VARIABLE):
        python, source = os.environ[PEER_PYTHON_VARIABLE], f"${PEER_PYTHON_VARIABLE}"
    else:
        python, source = str(DEFAULT_PEER_PYTHON), "the default"
    if not os.path.isfile(python):
        return None, f"not measured: no peer venv ({python}, {source}, does not exist; `make bench-dmc-venv` builds it)"
    return python, None


class Peer:
    """The worker process of ``benchmarks/control_suite_peer.py`` in the peer venv: one JSON line per request."""

    def __init__(self, python: str) -> None:
        self.stderr: IO[bytes] = tempfile.TemporaryFile()
        environment = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
        environment["MUJOCO_GL"] = "disable"  # no rendering back-end is needed or loaded
        self.process = subprocess.Popen(
            [python, str(PEER_SCRIPT)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.stderr,
            env=environment,
            text=True,
            cwd=ROOT,
        )
        self.hello = self._answer("start")["hello"]

    def _answer(self, doing: str) -> dict[str, Any]:
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        if not line:
            self.process.wait(timeout=60)
            self.stderr.seek(0)
            tail = self.stderr.read().decode(errors="replace").strip().splitlines()[-5:]
            raise RuntimeError(f"the peer worker exited ({self.process.returncode}) while {doing}: {' / '.join(tail)}")
        answer = json.loads(line)
        if "error" in answer:
            raise RuntimeError(f"the peer worker failed while {doing}: {answer['error']}\n{answer['traceback']}")
        return answer

    def call(self, op: str, **args: Any) -> dict[str, Any]:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps({"op": op, **args}) + "\n")
        self.process.stdin.flush()
        return self._answer(op)

    def close(self) -> None:
        if self.process.poll() is None:
            assert self.process.stdin is not None
            self.process.stdin.close()  # the end of stdin ends its loop; it closes its variants
            try:
                self.process.wait(timeout=120)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.stderr.close()


def run_task(
    task: str,
    num_envs: int,
    repeats: int,
    seconds: float,
    steps: int,
    num_threads: int,
    peer: Peer | None,
    peers: tuple[str, ...],
    workers: int,
    breakdown: bool = False,
) -> dict[str, Any]:
    """Every variant of ``task``, built once, measured back to back in each repeat: one row of the results."""
    load = os.getloadavg()
    started = time.perf_counter()
    ours = build_ours(task, num_envs, num_threads, steps, breakdown)
    ours_startup = time.perf_counter() - started
    peer_startup: dict[str, float] = {}
    if peer is not None:
        domain, name = task.split("-", 1)
        opened = peer.call(
            "open", domain=domain, task=name, num_envs=num_envs, variants=list(peers), steps_per_batch=steps,
            workers=workers, seed=0,
        )  # fmt: skip
        peer_startup = opened["startup_seconds"]
    measured = [*ours, *(peers if peer is not None else ())]
    raw: dict[str, list[float]] = {variant: [] for variant in measured}
    cpu: dict[str, list[float]] = {variant: [] for variant in measured}
    try:
        for _ in range(repeats):
            for variant in measured:
                if variant in ours:
                    result = measure(ours[variant], seconds)
                else:
                    assert peer is not None
                    result = peer.call("measure", variant=variant, seconds=seconds)
                raw[variant].append(result["frames_per_second"])
                cpu[variant].append(result["cpu_seconds_per_second"])
    finally:
        for variant in ours.values():
            variant.close()
        if peer is not None:
            peer.call("close")
    row: dict[str, Any] = {
        "task": task,
        "num_envs": num_envs,
        "load_average_before": load,
        "raw": raw,
        "cpu_seconds_per_second": cpu,
        "startup_seconds": {"ours": ours_startup, **peer_startup},
        "median": {variant: statistics.median(values) for variant, values in raw.items()},
        "ratio_to_floor": {
            variant: statistics.median(v / f for v, f in zip(values, raw["floor"], strict=True))
            for variant, values in raw.items()
            if variant != "floor"
        },
    }
    collected_peers = [variant for variant in TORCHRL_PEERS if variant in raw]
    if collected_peers:
        # the preset against the faster TorchRL peer of each repeat
        best = [max(raw[variant][k] for variant in collected_peers) for k in range(repeats)]
        row["preset_over_best_torchrl_peer"] = statistics.median(
            p / b for p, b in zip(raw["preset"], best, strict=True)
        )
    return row


COLUMNS = {
    "floor": "physics floor: Batch.step",
    "env": "env alone (÷ floor)",
    "preset": "preset (÷ floor)",
    "serial": "DMControlEnv SerialEnv (÷ floor)",
    "parallel": "DMControlEnv ParallelEnv of {workers} SerialEnv (÷ floor)",
    "parallel_pipes": "the same, use_buffers=False (÷ floor)",
    "parallel_per_env": "DMControlEnv ParallelEnv, 1 env per process (÷ floor)",
    "dm_control": "dm_control loop, no TorchRL (÷ floor)",
}


def _table(rows: list[dict[str, Any]], peers: tuple[str, ...], peer_status: str | None, workers: int) -> str:
    columns = ["task", "envs", *(COLUMNS[v].format(workers=workers) for v in (*OURS, *peers)), "preset ÷ TorchRL peer"]
    lines = ["| " + " | ".join(columns) + " |", "|---|" + "---:|" * (len(columns) - 1)]
    for row in rows:
        cells = [row["task"], str(row["num_envs"]), f"{row['median']['floor']:,.0f}"]
        for variant in (*OURS[1:], *peers):
            if variant in row["median"]:
                cells.append(f"{row['median'][variant]:,.0f} ({row['ratio_to_floor'][variant]:.2f})")
            else:
                cells.append(peer_status or "n/a")
        speedup = row.get("preset_over_best_torchrl_peer")
        cells.append(f"×{speedup:.1f}" if speedup is not None else (peer_status or "n/a"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _cpu_line(rows: list[dict[str, Any]]) -> str:
    """The CPU seconds per second each variant got, the median over tasks and repeats."""
    variants = list(dict.fromkeys(variant for row in rows for variant in row["cpu_seconds_per_second"]))
    shares = {
        variant: statistics.median(share for row in rows for share in row["cpu_seconds_per_second"].get(variant, ()))
        for variant in variants
    }
    return (
        "CPU seconds per second each variant got (its threads, or the peer's processes; the median over tasks and "
        "repeats): " + ", ".join(f"{variant} {share:.2f}" for variant, share in shares.items()) + "."
    )


def _breakdown_table(rows: list[dict[str, Any]]) -> str:
    """Milliseconds per step of all envs (the bracket: frames/s over the floor's) of ``--breakdown``'s variants."""
    variants = ("floor", "env", *LAYERS, "preset", NO_PHYSICS)
    lines = ["| task | " + " | ".join(variants) + " |", "|---|" + "---:|" * len(variants)]
    for row in rows:
        cells = [f"{1000 * row['num_envs'] / row['median']['floor']:.2f}"]
        for variant in variants[1:]:
            milliseconds = 1000 * row["num_envs"] / row["median"][variant]
            cells.append(f"{milliseconds:.2f} ({row['ratio_to_floor'][variant]:.2f})")
        lines.append(f"| {row['task']} × {row['num_envs']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _legend(num_threads: int, workers: int, steps: int, peers: tuple[str, ...]) -> str:
    items = [
        f"- physics floor: `mujoco.batch.Batch.step(nstep=frame_skip, stage=mjSTAGE_VEL)` of the env's own "
        f"persistent batch with {num_threads} threads, after writing random controls into its `ctrl` rows (MuJoCo "
        f"{mujoco.__version__}, no TorchRL, no reading, no reset); every ratio divides by the floor of its own "
        "repeat (the median ratio is shown).",
        f"- env alone: a `Collector` (uniform random actions, one torch thread, {steps} steps of all envs per batch) "
        "over `control_suite_base_env(task, N)`: the readings and TorchRL's per-step machinery, no task.",
        "- preset: the same `Collector` over `control_suite_env(task, N)`: the env + `StepCounter(1000)` + the "
        "task's `TaskTransform` + `ZeroBrokenStepReward` + `RewardSum`.",
    ]
    peer_items = {
        "serial": "- DMControlEnv SerialEnv: the same `Collector` over `SerialEnv(N, DMControlEnv(domain, task))` + "
        "`StepCounter(1000)` + `RewardSum()` (dm-control 1.0.50 on MuJoCo 3.17.0, in the peer venv), one process.",
        "parallel": f"- DMControlEnv ParallelEnv of {workers} SerialEnv: the same over `ParallelEnv({workers}, "
        f"SerialEnv(N / {workers}, DMControlEnv))`: one worker process per core.",
        "parallel_pipes": "- the same, use_buffers=False: the workers send their results through pipes, which the "
        "parent blocks on (the default, shared buffers, makes the parent spin-poll flags in shared memory while the "
        "workers step: a busy core).",
        "parallel_per_env": "- DMControlEnv ParallelEnv, 1 env per process: the same over `ParallelEnv(N, "
        "DMControlEnv)`, what `DMControlEnv(domain, task, num_workers=N)` builds.",
        "dm_control": "- dm_control loop: dm_control's own `env.step(action)` over the N envs in a Python loop (a "
        "finished episode reset), no TorchRL: what the TorchRL peers wrap.",
    }
    items += [peer_items[variant] for variant in peers]
    items.append(
        "- preset ÷ TorchRL peer: the preset's frames/s over the fastest TorchRL peer's (SerialEnv or ParallelEnv) of "
        "the same repeat, the median."
    )
    return "\n".join(items)


BREAKDOWN_TEXT = (
    "Where a step goes (`--breakdown`): milliseconds per step of all envs, medians (the bracket: frames/s over the "
    "floor's of the same repeat, the median): the floor, the env alone, then the preset's transforms added one at a "
    "time (`StepCounter(1000)`, the task's `TaskTransform`, `ZeroBrokenStepReward`; `RewardSum` makes the preset), "
    "and the preset's four transforms over an env with the base env's specs that simulates nothing "
    "(`benchmarks/pipeline_costs.py`'s `NoPhysicsEnv`: what TorchRL and the transforms cost per step without MuJoCo)."
)


def _versions() -> dict[str, str | None]:
    from importlib.metadata import PackageNotFoundError, version

    found: dict[str, str | None] = {}
    for name in ("torch", "torchrl", "tensordict", "numpy", "mujoco"):
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = None
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS), help="tasks (default: one per domain)")
    parser.add_argument("--envs", type=int, default=64, help="envs of every variant (%(default)s)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=1.0, help="time per measurement (%(default)s s)")
    parser.add_argument("--steps-per-batch", type=int, default=20, help="steps of all envs per batch (%(default)s)")
    parser.add_argument("--threads", type=int, default=None, help="MuJoCo threads (default: the CPUs of this process)")
    parser.add_argument(
        "--peers", nargs="*", default=list(DEFAULT_PEERS), choices=PEERS, help="peer variants (%(default)s)"
    )
    parser.add_argument("--peer-python", default=None, help=f"the peer venv's python (${PEER_PYTHON_VARIABLE})")
    parser.add_argument(
        "--breakdown",
        action="store_true",
        help="also the preset one transform at a time and over an env that simulates nothing (a second table)",
    )
    parser.add_argument("--output", type=Path, default=Path("runs/control_suite_bench"))
    parser.add_argument("--quick", action="store_true", help="every code path on one small task (timings mean nothing)")
    args = parser.parse_args(argv)
    unknown = [task for task in args.tasks if task not in CONTROL_SUITE_TASKS]
    if unknown:
        parser.error(f"unknown tasks {unknown}; the tasks are {', '.join(CONTROL_SUITE_TASKS)}")
    num_threads = args.threads or len(os.sched_getaffinity(0))
    tasks, num_envs, repeats, seconds, steps = args.tasks, args.envs, args.repeats, args.seconds, args.steps_per_batch
    if args.quick:
        tasks, num_envs, repeats, seconds, steps = ["cartpole-swingup"], 2, 1, 0.0, 2
    peers = tuple(args.peers)
    workers = min(num_threads, num_envs)
    if {"parallel", "parallel_pipes"} & set(peers) and num_envs % workers:
        parser.error(f"--envs ({num_envs}) must be a multiple of the parallel peer's {workers} workers")
    python, peer_status = peer_python(args.peer_python) if peers else (None, "not measured (--peers)")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"{len(tasks)} tasks × {num_envs} envs, {repeats} repeats, load average {load_before[0]:.2f}", flush=True)
    peer = Peer(python) if python is not None else None
    rows = []
    try:
        for task in tasks:
            rows.append(
                row := run_task(
                    task, num_envs, repeats, seconds, steps, num_threads, peer, peers, workers, args.breakdown
                )
            )
            print(
                f"{task}: "
                + ", ".join(f"{variant} {value:,.0f}" for variant, value in row["median"].items())
                + f" frames/s (load {row['load_average_before'][0]:.2f})",
                flush=True,
            )
    finally:
        if peer is not None:
            peer.close()
        torch.set_num_threads(threads)
    load_after = os.getloadavg()
    meta = {
        "command": shlex.join(["python", "benchmarks/control_suite.py", *(sys.argv[1:] if argv is None else argv)]),
        "started": started,
        "finished": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load_average_before": load_before,
        "load_average_after": load_after,
        "num_envs": num_envs,
        "repeats": repeats,
        "seconds": seconds,
        "steps_per_batch": steps,
        "threads": num_threads,
        "parallel_workers": workers,
        "torch_threads": 1,
        "quick": args.quick,
        "breakdown": args.breakdown,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "versions": _versions(),
        "peer_versions": peer.hello if peer is not None else None,
        "peer_status": peer_status,
    }
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2) + "\n")
    shown_peers = peers if peers else ()
    peer_versions = (
        ", ".join(f"{name} {value}" for name, value in peer.hello.items()) if peer is not None else peer_status
    )
    task_loads = ", ".join(f"{row['load_average_before'][0]:.1f}" for row in rows)
    (args.output / "results.md").write_text(
        f"frames/s, {num_envs} envs per variant, medians of {repeats} interleaved repeats of {seconds:g} s each; "
        f"{started} to {meta['finished']}, 1-minute load average {load_before[0]:.2f} before, {load_after[0]:.2f} "
        f"after (before each task: {task_loads}); "
        f"`{meta['command']}`; ours: "
        + ", ".join(f"{name} {value}" for name, value in meta["versions"].items())
        + f"; peer: {peer_versions}\n\n"
        f"{_table(rows, shown_peers, peer_status, workers)}\n\n{_legend(num_threads, workers, steps, shown_peers)}\n\n"
        f"{_cpu_line(rows)}\n" + (f"\n{BREAKDOWN_TEXT}\n\n{_breakdown_table(rows)}\n" if args.breakdown else "")
    )
    print((args.output / "results.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
