"""T1 at batch 16384 under the process's allocator: ``python benchmarks/allocator.py [--batch N]``.

Times the public eager ``task.transition`` and the two hand-fused floors (``fused_t1``, ``fused_t1_lean``)
in one process and prints µs per call. Run it twice to see how much glibc's allocator decides:

    python benchmarks/allocator.py
    MALLOC_MMAP_THRESHOLD_=4000000000 MALLOC_TRIM_THRESHOLD_=4000000000 python benchmarks/allocator.py

With the thresholds raised, freed pages stay with the process; with the defaults a function whose
``[B, n]`` temporaries cross the mmap threshold may fault its pages in again on every call.
"""

from __future__ import annotations

import argparse
import os

import torch

from torchtasks.bench.cases import BenchConfig, make_t1
from torchtasks.bench.fused import FusedConstants, fused_t1, fused_t1_lean
from torchtasks.bench.timing import median_time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=16384)
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = BenchConfig()
    task = make_t1(config).float()
    constants = FusedConstants.of(config)
    generator = torch.Generator().manual_seed(0)
    state = torch.rand(args.batch, config.state_size, generator=generator) * 1.6 - 0.8
    next_state = state + 0.01
    action = torch.rand(args.batch, config.action_size, generator=generator) * 2 - 1
    truncated = torch.zeros(args.batch, dtype=torch.bool)
    paid = torch.zeros(args.batch, dtype=torch.bool)
    memory = task.reset(state)
    names = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
    settings = {key: os.environ[key] for key in names if key in os.environ}
    print(f"batch {args.batch}, allocator settings: {settings or 'glibc defaults'}")
    with torch.no_grad():
        timings = {
            "task.transition (eager)": lambda: task.transition(state, action, next_state, memory, truncated=truncated),
            "fused_t1 (eager)": lambda: fused_t1(constants, next_state, action, truncated, paid),
            "fused_t1_lean (eager)": lambda: fused_t1_lean(constants, next_state, action, truncated, paid),
        }
        for name, fn in timings.items():
            print(f"{name:26s} {median_time(fn, repeats=7, min_seconds=0.2) * 1e6:9.1f} µs per call")


if __name__ == "__main__":
    main()
