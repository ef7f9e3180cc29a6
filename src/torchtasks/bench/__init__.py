"""The torchtasks benchmark suite (``torchtasks bench``): task evaluation, collector overhead, memory.

Every figure is a ratio measured in the same run (medians of repeats), so the results say how
torchtasks compares with its baselines on the machine at hand, not absolute speeds.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import torch

from torchtasks._checks import check_positive_int

__all__ = ["format_markdown", "run_benchmarks"]

SECTIONS = ("tasks", "collector", "memory")


def _machine() -> dict[str, Any]:
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }


def run_benchmarks(
    output_dir: str | Path | None = "runs/bench",
    *,
    tiny: bool = False,
    sections: list[str] | None = None,
    threads: int | None = 1,
) -> dict[str, Any]:
    """Run the selected sections and write ``benchmarks.json`` and ``benchmarks.md`` to ``output_dir``.

    ``tiny`` runs every code path on tiny sizes (a smoke test: timings are meaningless).
    ``threads`` sets torch's intra-op threads for the run (default 1: on a 2-core machine a second
    OpenMP thread competes with the env, the collector and anything else running, and made
    element-wise ops up to 50x slower in our measurements; ``None`` keeps torch's default).
    """
    threads = None if threads is None else check_positive_int(threads, "threads")
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        return _run(output_dir, tiny=tiny, sections=sections)
    finally:
        torch.set_num_threads(previous)


def _run(output_dir: str | Path | None, *, tiny: bool, sections: list[str] | None) -> dict[str, Any]:
    from torchtasks.bench.task_eval import memory_bytes_per_env, run_task_benchmark

    chosen = tuple(sections) if sections else SECTIONS
    unknown = set(chosen) - set(SECTIONS)
    if unknown:
        raise ValueError(f"unknown benchmark sections {sorted(unknown)}; choose from {list(SECTIONS)}")
    cases = _cases(tiny)
    results: dict[str, Any] = {"machine": _machine(), "tiny": tiny}
    if "tasks" in chosen:
        results["tasks"] = run_task_benchmark(
            names=tuple(cases),
            batches=(1, 8) if tiny else (1, 64, 1024, 16384),
            compile=True,
            backend="aot_eager" if tiny else "inductor",  # tiny: trace every graph, skip Inductor's codegen
            repeats=1 if tiny else 5,
            min_seconds=0.001 if tiny else 0.1,
            extra_cases={name: case for name, case in cases.items() if case is not None},
        )
    if "collector" in chosen:
        from torchtasks.bench.collector import run_collector_benchmark

        results["collector"] = run_collector_benchmark(tiny=tiny)
    if "memory" in chosen:
        results["memory"] = [
            {"case": name, "bytes_per_env": memory_bytes_per_env(*_memory_case(name, case))}
            for name, case in cases.items()
        ]
    if output_dir is not None:
        folder = Path(output_dir)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "benchmarks.json").write_text(json.dumps(results, indent=2))
        (folder / "benchmarks.md").write_text(format_markdown(results))
    print(format_markdown(results))
    return results


def _cases(tiny: bool) -> dict[str, Any]:
    cases: dict[str, Any] = {"T1": None, "T2": None, "T3": None}
    try:
        from torchtasks.bench.locomotion_case import HalfCheetahCase
    except ImportError:  # the mujoco extra is missing
        return cases
    cases["T4"] = HalfCheetahCase()
    return cases


def _memory_case(name: str, case: Any) -> tuple[Any, int]:
    from torchtasks.bench.cases import BenchConfig, make_t1, make_t2, make_t3

    if case is not None:
        return case.task(), case.state_size
    config = BenchConfig()
    return {"T1": make_t1, "T2": make_t2, "T3": make_t3}[name](config), config.state_size


def format_markdown(results: dict[str, Any]) -> str:
    """Return the results as Markdown tables."""
    lines = ["# torchtasks benchmarks", ""]
    machine = results["machine"]
    lines.append(
        f"Machine: {machine['processor']}, {machine['cpus']} CPUs, torch {machine['torch']} "
        f"({machine['torch_threads']} threads), Python {machine['python']}, {machine['date']}."
    )
    if results.get("tiny"):
        lines += ["", "**Tiny smoke run: the timings below are not meaningful.**"]
    if "tasks" in results:
        lines += [
            "",
            "## Task evaluation: one public `task.transition(...)` call per batch of transitions",
            "",
            "Times in µs per call for the whole batch. The floor is the hand-fused function (the same maths "
            "on plain tensors, no task objects, no validation): `eager / fused` compares eager with eager and "
            "`compiled / fused compiled` compiled with compiled (`torch.compile(fullgraph=True)` of "
            "`task.transition` and of the fused function). `speedup` = per-env numpy loop (Pyrado-style) / "
            "eager `transition`.",
            "",
            "| case | batch | eager | hand-fused | eager / fused | compiled | fused compiled "
            "| compiled / fused compiled | numpy loop | speedup |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for row in results["tasks"]:
            us = row["us"]
            compiled_ratio = row.get("compiled_over_fused_compiled", float("nan"))
            lines.append(
                f"| {row['case']} | {row['batch']} | {us['eager']:.1f} | {us['fused']:.1f} | "
                f"{row['eager_over_fused']:.2f}x | {us.get('compiled', float('nan')):.1f} | "
                f"{us.get('fused_compiled', float('nan')):.1f} | {compiled_ratio:.2f}x | "
                f"{us['numpy_loop']:.1f} | {row['eager_speedup_vs_numpy_loop']:.1f}x |"
            )
        lean = [row for row in results["tasks"] if "eager_over_fused_lean" in row]
        if lean:
            lines += [
                "",
                "T1 against a second floor, the hand-fused function written with torchtasks' own op choices "
                "(`fused_t1_lean`: mat-vec quadratic forms, bounds by clamp and count instead of bool `any`):",
                "",
                "| case | batch | eager | lean fused | eager / lean fused |",
                "|---|---:|---:|---:|---:|",
            ]
            lines += [
                f"| {row['case']} | {row['batch']} | {row['us']['eager']:.1f} | {row['us']['fused_lean']:.1f} | "
                f"{row['eager_over_fused_lean']:.2f}x |"
                for row in lean
            ]
    if "collector" in results:
        lines += [
            "",
            "## Collector overhead (frames/s, uniform random actions, StepCounter(1000) + transform)",
            "",
            "| setup | identity | TaskTransform(T1) | minimal T1 | task / identity | minimal / identity "
            "| task / minimal | TaskTransform(T1, log_terms=False) | fewest-entries T1 | no terms / fewest |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for row in results["collector"]:
            fps = row["fps"]
            lines.append(
                f"| {row['setup']} | {fps['identity']:,.0f} | {fps['task']:,.0f} | {fps['minimal']:,.0f} | "
                f"{row['task_over_identity']:.2f} | {row['minimal_over_identity']:.2f} | "
                f"{row['task_over_minimal']:.2f} | {fps['task_no_terms']:,.0f} | {fps['fewest']:,.0f} | "
                f"{row['no_terms_over_fewest']:.2f} |"
            )
    if "memory" in results:
        lines += ["", "## Task memory", "", "| case | bytes per env |", "|---|---:|"]
        lines += [f"| {row['case']} | {row['bytes_per_env']} |" for row in results["memory"]]
    return "\n".join(lines) + "\n"
