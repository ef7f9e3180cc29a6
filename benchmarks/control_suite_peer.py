"""The peer side of ``benchmarks/control_suite.py``: TorchRL's ``DMControlEnv`` (dm-control 1.0.50, MuJoCo 3.17.0).

A standalone script run by the benchmark venv's python (``make bench-dmc-venv``: torch, torchrl, tensordict,
mujoco 3.17.0 and dm-control 1.0.50, no torchtasks; dm-control does not import on MuJoCo 4). It serves requests,
one JSON object per line on stdin, and answers one JSON object per line on stdout (anything else the libraries print
goes to stderr). The first line is its hello (the versions). Requests:

- ``{"op": "open", "domain": ..., "task": ..., "num_envs": N, "variants": [...], "steps_per_batch": S,
  "workers": W, "seed": 0}``: builds every variant (closing those of the task before), draws one untimed batch of
  each, and answers their start-up seconds.
- ``{"op": "measure", "variant": ..., "seconds": T}``: draws batches of ``N * S`` frames from the variant until ``T``
  seconds have passed (at least one batch) and answers ``{"frames": ..., "seconds": ..., "frames_per_second": ...,
  "cpu_seconds_per_second": ...}``: the CPU seconds this process and its worker processes got per second (Linux's
  ``/proc``; elsewhere this process's only).
- ``{"op": "close"}`` closes the variants; the end of stdin ends the worker.

Errors answer ``{"error": message, "traceback": ...}`` and the worker keeps serving.

The variants (N envs of ``DMControlEnv(domain, task)`` each):

- ``serial``: a ``Collector`` (uniform random actions, one ``torch.rand`` per step, as the benchmark's own
  Collectors) over ``TransformedEnv(SerialEnv(N, make), Compose(StepCounter(1000), RewardSum()))``: every env
  stepped in turn in this process.
- ``parallel``: the same over ``ParallelEnv(W, SerialEnv(N / W, make))``: W worker processes (one per core), each
  stepping N / W envs in turn. TorchRL 0.14.1's parent spin-polls shared-memory flags while the workers step
  (``ParallelEnv._wait_for_workers``): it keeps a core busy.
- ``parallel_pipes``: the same with ``use_buffers=False``: the workers send their results through pipes, which the
  parent blocks on.
- ``parallel_per_env``: the same over ``ParallelEnv(N, make)``: one worker process per env, what
  ``DMControlEnv(domain, task, num_workers=N)`` builds.
- ``dm_control``: dm_control alone: a Python loop of ``env.step(action)`` over N ``suite.load(domain, task)`` envs
  (uniform random actions drawn beforehand, a finished episode reset), no TorchRL.
"""

from __future__ import annotations

import functools
import json
import os
import sys
import time
import traceback
from typing import Any

VARIANTS = ("serial", "parallel", "parallel_pipes", "parallel_per_env", "dm_control")


def _uniform_actions(env: Any) -> Any:
    """The benchmarks' policy (``torchtasks.bench.collector.UniformActions``, copied: torchtasks is not installed
    here): writes ``"action"``, uniform within the env's action bounds, one ``torch.rand`` per step."""
    import torch
    from tensordict.nn import TensorDictModuleBase

    class UniformActions(TensorDictModuleBase):
        def __init__(self) -> None:
            super().__init__()
            self.in_keys: list[str] = []
            self.out_keys: list[str] = ["action"]
            space = env.action_spec.space
            self.register_buffer("low", torch.as_tensor(space.low).expand(env.action_spec.shape).clone())
            self.register_buffer("width", torch.as_tensor(space.high).expand(env.action_spec.shape) - self.low)

        def forward(self, tensordict: Any) -> Any:
            action = torch.rand(self.low.shape, dtype=self.low.dtype, device=self.low.device) * self.width + self.low
            return tensordict.set("action", action)

    return UniformActions()


class _Collected:
    """A variant measured through an endless ``Collector`` (stopped by hand, first batch drawn at start-up)."""

    def __init__(self, env: Any, frames_per_batch: int) -> None:
        from torchrl.collectors import Collector

        self.collector = Collector(
            env,
            policy=_uniform_actions(env),
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


class _DmControlLoop:
    """dm_control alone: ``env.step`` of each env in turn, a finished episode reset."""

    def __init__(self, domain: str, task: str, num_envs: int, steps: int, seed: int) -> None:
        import numpy as np
        from dm_control import suite

        self.envs = [suite.load(domain, task, task_kwargs={"random": seed + i}) for i in range(num_envs)]
        for env in self.envs:
            env.reset()
        spec = self.envs[0].action_spec()
        generator = np.random.default_rng(seed)
        self.actions = generator.uniform(spec.minimum, spec.maximum, size=(steps, num_envs, *spec.shape))
        self.batch()

    def batch(self) -> int:
        for action in self.actions:
            for env, a in zip(self.envs, action, strict=True):
                if env.step(a).last():
                    env.reset()
        return self.actions.shape[0] * len(self.envs)

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _counted(env: Any) -> Any:
    from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

    return TransformedEnv(env, Compose(StepCounter(1000), RewardSum()))


def _build(variant: str, domain: str, task: str, num_envs: int, steps: int, workers: int, seed: int) -> Any:
    from torchrl.envs import DMControlEnv, ParallelEnv, SerialEnv

    make = functools.partial(DMControlEnv, domain, task)
    if variant == "dm_control":
        return _DmControlLoop(domain, task, num_envs, steps, seed)
    if variant == "serial":
        env = SerialEnv(num_envs, make)
    elif variant in ("parallel", "parallel_pipes"):
        if num_envs % workers:
            raise ValueError(f"{variant}: num_envs ({num_envs}) must be a multiple of workers ({workers})")
        # use_buffers=False: the workers send their results through pipes, which the parent blocks on; with buffers
        # (the default) the parent spin-polls shared-memory flags while the workers step
        use_buffers = None if variant == "parallel" else False
        env = ParallelEnv(workers, functools.partial(SerialEnv, num_envs // workers, make), use_buffers=use_buffers)
    elif variant == "parallel_per_env":
        env = ParallelEnv(num_envs, make)
    else:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    env.set_seed(seed)
    return _Collected(_counted(env), num_envs * steps)


def _cpu_seconds() -> float:
    """CPU seconds of this process (all threads) and of its running child processes (a ParallelEnv's workers)."""
    total = time.process_time()
    if not os.path.isdir("/proc"):
        return total
    me, tick = os.getpid(), os.sysconf("SC_CLK_TCK")
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()  # after the command name, which may hold spaces
        except OSError:  # exited meanwhile
            continue
        if int(fields[1]) == me:  # ppid; then utime and stime in clock ticks
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


class Server:
    """The variants of the open task, by name."""

    def __init__(self) -> None:
        self.open_variants: dict[str, Any] = {}

    def open(self, domain: str, task: str, num_envs: int, variants: list[str], steps_per_batch: int,
             workers: int, seed: int = 0) -> dict[str, Any]:  # fmt: skip
        self.close()
        startup = {}
        for variant in variants:
            started = time.perf_counter()
            self.open_variants[variant] = _build(variant, domain, task, num_envs, steps_per_batch, workers, seed)
            startup[variant] = time.perf_counter() - started
        return {"startup_seconds": startup}

    def measure(self, variant: str, seconds: float) -> dict[str, float]:
        if variant not in self.open_variants:
            raise ValueError(f"variant {variant!r} is not open (open: {sorted(self.open_variants)})")
        measured = self.open_variants[variant]
        frames, elapsed, cpu = 0, 0.0, _cpu_seconds()
        started = time.perf_counter()
        while elapsed < seconds or frames == 0:
            frames += measured.batch()
            elapsed = time.perf_counter() - started
        cpu = _cpu_seconds() - cpu
        return {
            "frames": frames,
            "seconds": elapsed,
            "frames_per_second": frames / elapsed,
            "cpu_seconds_per_second": cpu / elapsed,
        }

    def close(self) -> dict[str, Any]:
        while self.open_variants:
            _, measured = self.open_variants.popitem()
            measured.close()
        return {}


def _versions() -> dict[str, str]:
    from importlib.metadata import version

    return {name: version(name) for name in ("torch", "torchrl", "tensordict", "mujoco", "dm-control", "numpy")}


def main() -> int:
    # answers go to the original stdout; whatever the libraries print goes to stderr
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "w", buffering=1)
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    import torch

    torch.set_num_threads(1)
    server = Server()
    answers.write(json.dumps({"hello": _versions(), "pid": os.getpid()}) + "\n")
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            request = json.loads(line)
            op = request.pop("op")
            if op not in ("open", "measure", "close"):
                raise ValueError(f"op must be open, measure or close, got {op!r}")
            answer = getattr(server, op)(**request)
        except Exception as error:  # every error is answered, and the worker keeps serving
            answer = {"error": f"{type(error).__name__}: {error}", "traceback": traceback.format_exc()}
        answers.write(json.dumps(answer) + "\n")
    server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
