"""What the sim-to-real perturbations cost, counted in CPU instructions: a measure the machine's speed does not move.

``python benchmarks/perturbations_instructions.py [--envs 64] [--batches 8] [--steps-per-batch 20] [--threads 2]
[--variants plain "all four" ...] [--output runs/perturbations_instructions]``  (needs ``valgrind``)

Each variant of ``benchmarks/perturbations.py`` (the velocity-tracking preset in a ``Collector`` with uniform random
actions) runs in its own process under ``valgrind --tool=callgrind`` with the instrumentation off; after two warm-up
batches it is switched on (``callgrind_control -i on``) for ``--batches`` batches and off again, and the
instructions counted (everything the process ran: Python, torch, TorchRL, MuJoCo) are divided by the steps. The
actions, the preset's generators and so the trajectories are seeded alike in every variant (``torch.manual_seed(0)``
before the collector is built): a perturbation that changes the dynamics (pushes, delays, gains) still changes
where the envs reset, so its count includes the resets it causes. Wall time under valgrind is some 50x the native
one: the default (8 batches of 20 steps, six variants, two at a time) takes about 10 minutes. The cost of a variant
is its instructions per step over the plain preset's; a wall-clock cost is larger where the added work is small
tensor operations (allocations, dispatch), which run fewer instructions per cycle than the physics. Results:
``<output>/results.json`` and ``<output>/results.md``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the variants counted by default
DEFAULT_VARIANTS = ("plain", "delay", "noise", "pushes", "gains", "all four", "records alone")


def worker(variant: str, envs: int, threads: int, steps: int, batches: int, handshake: Path) -> None:
    """Run in the valgrind process: build the variant, warm up, then signal and wait around the counted batches."""
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from perturbations import PARTS, Collected, preset

    torch.set_num_threads(1)
    torch.manual_seed(0)
    collected = Collected(preset(envs, threads, PARTS[variant]), envs * steps)
    try:
        for _ in range(2):
            collected.batch()
        _signal_and_wait(handshake, "ready", "go")
        for _ in range(batches):
            collected.batch()
        _signal_and_wait(handshake, "done", "end")
    finally:
        collected.close()


def _signal_and_wait(handshake: Path, signal: str, wait: str) -> None:
    (handshake / signal).touch()
    while not (handshake / wait).exists():
        time.sleep(0.1)


def _wait_for(path: Path, process: subprocess.Popen) -> None:
    while not path.exists():
        if process.poll() is not None:
            raise RuntimeError(f"the counted process ended early (exit code {process.returncode}); see its log")
        time.sleep(0.5)


def launch(variant: str, args: argparse.Namespace, where: Path) -> tuple[subprocess.Popen, Path]:
    """Start one variant's valgrind process (instrumentation off); its handshake directory is returned."""
    handshake = where / variant.replace(" ", "_").replace(",", "")
    handshake.mkdir()
    command = [
        "valgrind",
        "--tool=callgrind",
        "--instr-atstart=no",
        f"--callgrind-out-file={handshake / 'callgrind.out'}",
        sys.executable,
        str(Path(__file__).resolve()),
        "--worker",
        variant,
        f"--envs={args.envs}",
        f"--threads={args.threads}",
        f"--steps-per-batch={args.steps_per_batch}",
        f"--batches={args.batches}",
        f"--handshake={handshake}",
    ]
    with open(handshake / "log", "w") as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
    return process, handshake


def count(process: subprocess.Popen, handshake: Path) -> int:
    """Switch the counting on around the variant's batches; the instructions counted."""
    _wait_for(handshake / "ready", process)
    subprocess.run(["callgrind_control", "-i", "on", str(process.pid)], check=True, capture_output=True)
    (handshake / "go").touch()
    _wait_for(handshake / "done", process)
    subprocess.run(["callgrind_control", "-i", "off", str(process.pid)], check=True, capture_output=True)
    (handshake / "end").touch()
    if process.wait() != 0:
        raise RuntimeError(f"the counted process failed (exit code {process.returncode}); see {handshake / 'log'}")
    return totals(handshake / "callgrind.out")


def totals(path: Path) -> int:
    """The instruction count of a callgrind output file (its ``totals:`` line)."""
    for line in path.read_text().splitlines():
        if line.startswith("totals:"):
            return int(line.split()[1])
    raise ValueError(f"{path} has no 'totals:' line: not a callgrind output")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=64, help="envs of the batch (default 64)")
    parser.add_argument("--batches", type=int, default=8, help="counted batches per variant (default 8)")
    parser.add_argument("--steps-per-batch", type=int, default=20, help="steps per Collector batch (default 20)")
    parser.add_argument("--threads", type=int, default=2, help="MuJoCo threads (default 2)")
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS), help="variants of perturbations.py")
    parser.add_argument("--output", type=Path, default=Path("runs/perturbations_instructions"), help="results")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--handshake", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker(args.worker, args.envs, args.threads, args.steps_per_batch, args.batches, args.handshake)
        return 0
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from perturbations import PARTS

    unknown = [variant for variant in args.variants if variant not in PARTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; the variants are {list(PARTS)}")
    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        print("this benchmark needs valgrind (valgrind and callgrind_control on the PATH)", file=sys.stderr)
        return 2
    variants = ["plain", *[variant for variant in args.variants if variant != "plain"]]
    steps = args.batches * args.steps_per_batch
    started, counted = time.perf_counter(), {}
    with tempfile.TemporaryDirectory() as where:
        for first in range(0, len(variants), 2):  # two at a time: the counts do not depend on the load
            pair = variants[first : first + 2]
            running = [(variant, *launch(variant, args, Path(where))) for variant in pair]
            for variant, process, handshake in running:
                counted[variant] = count(process, handshake) / steps
    result = {
        "command": shlex.join(["python", "benchmarks/perturbations_instructions.py", *(argv or sys.argv[1:])]),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "envs": args.envs,
        "steps": steps,
        "instructions_per_step": counted,
        "cost": {variant: value / counted["plain"] - 1 for variant, value in counted.items() if variant != "plain"},
        "wall_seconds": time.perf_counter() - started,
    }
    lines = [
        f"{result['date']}, `{result['command']}`: x{args.envs} envs, {steps} counted steps per variant",
        "",
        "| variant | instructions per step | vs plain |",
        "|---|---:|---:|",
    ]
    for variant, value in counted.items():
        cost = "" if variant == "plain" else f"{100 * result['cost'][variant]:+.2f}%"
        lines.append(f"| {variant} | {value / 1e6:,.2f} M | {cost} |")
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "results.json").write_text(json.dumps(result, indent=2))
    (args.output / "results.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"results: {args.output / 'results.json'}, {args.output / 'results.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
