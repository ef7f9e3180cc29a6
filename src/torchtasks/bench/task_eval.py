"""Task-evaluation benchmark: the public ``Task.transition`` against a Pyrado loop and hand-fused torch.

What is timed is what a user calls: ``task.transition(state, action, next_state, memory, truncated=...)``,
validation included, eager and under ``torch.compile(fullgraph=True)``. The hand-fused function does
the same maths on plain tensors; it is timed eager and compiled, and each torchtasks variant is
compared with the fused variant of the same kind (eager with eager, compiled with compiled).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from torchtasks.bench.cases import BenchConfig, make_t1, make_t2, make_t3
from torchtasks.bench.fused import FusedConstants, fused_parallel, fused_sequential, fused_t1, fused_t1_lean
from torchtasks.bench.pyrado_loop import PyradoLoop
from torchtasks.bench.timing import median_time
from torchtasks.tasks import Task

__all__ = ["memory_bytes_per_env", "run_task_benchmark", "task_step"]


def task_step(
    task: Task,
    state: torch.Tensor,
    action: torch.Tensor,
    next_state: torch.Tensor,
    truncated: torch.Tensor,
    memory: TensorDictBase,
) -> tuple[torch.Tensor, torch.Tensor, TensorDictBase]:
    """One transition through the public call: ``(reward, done, memory)`` of ``task.transition``."""
    out = task.transition(state, action, next_state, memory, truncated=truncated)
    return out.reward, out.done, out.memory


def memory_bytes_per_env(task: Task, state_size: int) -> int:
    """Bytes of task memory per environment (batch of one)."""
    memory = task.reset(torch.zeros(1, state_size))
    return sum(leaf.element_size() * leaf.numel() for leaf in memory.values(include_nested=True, leaves_only=True))


def _fused(name: str, constants: FusedConstants, batch: int, k: int) -> tuple[Callable[..., Any], tuple[Any, ...]]:
    flags = torch.zeros(batch, k, dtype=torch.bool)
    if name == "T1":
        return fused_t1, (torch.zeros(batch, dtype=torch.bool),)
    if name == "T2":
        return fused_parallel, (flags, flags.clone(), flags.clone())
    return fused_sequential, (torch.zeros(batch, dtype=torch.long), flags, flags.clone(), flags.clone())


def _check_same_maths(name: str, task: Task, constants: FusedConstants, config: BenchConfig) -> None:
    """Assert that torchtasks and the fused function agree on a batch with successes and failures."""
    generator = torch.Generator().manual_seed(0)
    batch = 256
    state = (torch.rand(batch, config.state_size, generator=generator) * 2.4 - 1.2) * 0.5
    next_state = state.flip(0)
    next_state[:8] = config.goals[0]
    next_state[8:16] = config.bound * 1.5
    action = torch.rand(batch, config.action_size, generator=generator)
    truncated = torch.rand(batch, generator=generator) < 0.1
    memory = task.reset(state)
    expected_reward, expected_done, _ = task_step(task, state, action, next_state, truncated, memory)
    fn, extra = _fused(name, constants, batch, len(config.goals))
    functions = [fn, fused_t1_lean] if name == "T1" else [fn]
    for function in functions:
        reward, done, *_ = function(constants, next_state, action, truncated, *extra)  # then the fused memory
        if not (torch.allclose(expected_reward, reward, rtol=1e-5, atol=1e-5) and torch.equal(expected_done, done)):
            raise AssertionError(f"{name}: {function.__name__} does not compute what the task computes")


def run_task_benchmark(
    names: tuple[str, ...] = ("T1", "T2", "T3"),
    batches: tuple[int, ...] = (1, 64, 1024, 16384),
    *,
    compile: bool = True,
    backend: str = "inductor",
    config: BenchConfig | None = None,
    repeats: int = 5,
    min_seconds: float = 0.05,
    extra_cases: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Time one task step per case and batch size; return one row per (case, batch) with times [µs] and ratios.

    ``backend`` is the ``torch.compile`` backend of the compiled paths (``"aot_eager"`` traces the
    same graphs without Inductor's code generation: a fast smoke run).
    """
    config = config or BenchConfig()
    makers = {"T1": make_t1, "T2": make_t2, "T3": make_t3}
    rows = []
    for name in names:
        case = (extra_cases or {}).get(name)
        for batch in batches:
            rows.append(
                _time_case(
                    name,
                    batch,
                    config,
                    makers.get(name),
                    case,
                    compile=compile,
                    backend=backend,
                    repeats=repeats,
                    min_seconds=min_seconds,
                )
            )
    return rows


def _time_case(
    name: str,
    batch: int,
    config: BenchConfig,
    maker: Callable[[BenchConfig], Task] | None,
    case: Any,
    *,
    compile: bool,
    backend: str,
    repeats: int,
    min_seconds: float,
) -> dict[str, Any]:
    lean_fn = None
    if case is not None:
        task, state, action, next_state, fused_fn, fused_args, loop_step = case.build(batch)
    else:
        task = maker(config).float()
        generator = torch.Generator().manual_seed(batch)
        state = torch.rand(batch, config.state_size, generator=generator) * 1.6 - 0.8
        next_state = state + 0.01 * torch.rand(batch, config.state_size, generator=generator)
        action = torch.rand(batch, config.action_size, generator=generator) * 2 - 1
        constants = FusedConstants.of(config)
        if batch == 1:
            _check_same_maths(name, task, constants, config)
        fn, extra = _fused(name, constants, batch, len(config.goals))
        fused_fn, fused_args = fn, (constants, next_state, action, torch.zeros(batch, dtype=torch.bool), *extra)
        if name == "T1":
            lean_fn = fused_t1_lean
        loop = PyradoLoop(name, config, batch)
        next_state_np, action_np = next_state.double().numpy(), action.double().numpy()
        truncated_np = np.zeros(batch, dtype=bool)

        def loop_step() -> object:
            return loop.step(next_state_np, action_np, truncated_np)

    truncated = torch.zeros(batch, dtype=torch.bool)
    memory = task.reset(state)
    times: dict[str, float] = {}
    with torch.no_grad():
        times["eager"] = median_time(
            lambda: task.transition(state, action, next_state, memory, truncated=truncated),
            repeats=repeats,
            min_seconds=min_seconds,
        )
        times["fused"] = median_time(lambda: fused_fn(*fused_args), repeats=repeats, min_seconds=min_seconds)
        if lean_fn is not None:
            times["fused_lean"] = median_time(lambda: lean_fn(*fused_args), repeats=repeats, min_seconds=min_seconds)
        if compile:
            torch._dynamo.reset()
            compiled = torch.compile(task.transition, fullgraph=True, dynamic=False, backend=backend)
            times["compiled"] = median_time(
                lambda: compiled(state, action, next_state, memory, truncated=truncated),
                repeats=repeats,
                min_seconds=min_seconds,
            )
            fused_compiled = torch.compile(fused_fn, fullgraph=True, dynamic=False, backend=backend)
            times["fused_compiled"] = median_time(
                lambda: fused_compiled(*fused_args), repeats=repeats, min_seconds=min_seconds
            )
        loop_repeats = 3 if batch >= 4096 else repeats
        times["numpy_loop"] = median_time(loop_step, repeats=loop_repeats, min_seconds=min_seconds, warmup=1)
    row = {
        "case": name,
        "batch": batch,
        "us": {key: value * 1e6 for key, value in times.items()},
        "eager_speedup_vs_numpy_loop": times["numpy_loop"] / times["eager"],
        "eager_over_fused": times["eager"] / times["fused"],
    }
    if lean_fn is not None:
        row["eager_over_fused_lean"] = times["eager"] / times["fused_lean"]
    if compile:
        row["compiled_over_fused_compiled"] = times["compiled"] / times["fused_compiled"]
    return row
