"""The ``torchtasks`` command: ``demo``, ``list``, ``check`` and ``bench``."""

from __future__ import annotations

import argparse
import importlib
import inspect
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["PARITY_TOLERANCE", "catalogue", "main"]

#: largest absolute reward difference to Gymnasium that ``torchtasks check`` accepts
PARITY_TOLERANCE = 1e-5

_SECTIONS = (
    ("Reward functions", "torchtasks.rewards"),
    ("Tasks", "torchtasks.tasks"),
    ("Factories", "torchtasks.predefined"),
    ("Environments and presets", "torchtasks.envs"),
)


def _summary(obj: object) -> str:
    doc = inspect.getdoc(obj) or ""
    return doc.strip().splitlines()[0] if doc.strip() else "(no description)"


def catalogue() -> list[tuple[str, list[tuple[str, str]]]]:
    """Return ``[(section, [(name, one-line description), ...]), ...]`` of the public API.

    Example:
        >>> sections = dict(catalogue())
        >>> any(name == "QuadraticErrorReward" for name, _ in sections["Reward functions"])
        True
    """
    result = []
    for title, module_name in _SECTIONS:
        module = importlib.import_module(module_name)
        entries = [(name, _summary(getattr(module, name))) for name in module.__all__]
        result.append((title, entries))
    return result


def _cmd_list(args: argparse.Namespace) -> int:
    for title, entries in catalogue():
        print(f"\n{title}")
        width = max(len(name) for name, _ in entries)
        for name, summary in entries:
            print(f"  {name:<{width}}  {summary}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from torchtasks.demo import format_result, run_demo

    frames = 32_000 if args.quick else 320_000
    print("torchtasks demo: a swing-up task on 64 batched torch pendulums inside a TorchRL Collector;")
    print("a classical controller acts, the task decides rewards, successes and episode ends.")
    result = run_demo(total_frames=frames, output_dir=args.output, progress=not args.no_progress, seed=args.seed)
    print(format_result(result))
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    try:
        from torchtasks.parity import check_parity, format_parity_table
    except ImportError as error:  # pragma: no cover - depends on the optional mujoco extra
        print(f"torchtasks check needs the 'mujoco' extra (mujoco, gymnasium, imageio): {error}", file=sys.stderr)
        return 2
    env_ids = args.env_ids
    rows = [check_parity(env_id, seeds=tuple(range(args.seeds)), steps=args.steps) for env_id in env_ids]
    print(format_parity_table(rows))
    mismatched = [
        row["env"]
        for row in rows
        if row["max_abs_reward_diff"] > PARITY_TOLERANCE
        or row["termination_mismatches"]
        or row["observation_mismatches"]
    ]
    if mismatched:
        print(f"parity NOT met (reward tolerance {PARITY_TOLERANCE}) for: {', '.join(mismatched)}", file=sys.stderr)
    return 1 if mismatched else 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from torchtasks.bench import run_benchmarks

    run_benchmarks(output_dir=Path(args.output), tiny=args.tiny, sections=args.sections, threads=args.threads or None)
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torchtasks", description="Batched, differentiable tasks for TorchRL.")
    commands = parser.add_subparsers(dest="command", required=True)

    demo = commands.add_parser("demo", help="run a task chain inside a TorchRL Collector and summarise it")
    demo.add_argument("--quick", action="store_true", help="a short run (a few seconds)")
    demo.add_argument("--output", default=".", help="folder of the PNG plot (default: the current folder)")
    demo.add_argument("--seed", type=int, default=0, help="random seed")
    demo.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    demo.set_defaults(run=_cmd_demo)

    listing = commands.add_parser("list", help="list reward functions, tasks, factories and presets")
    listing.set_defaults(run=_cmd_list)

    check = commands.add_parser("check", help="compare a Gymnasium MuJoCo preset with Gymnasium, step by step")
    check.add_argument("env_ids", nargs="+", metavar="ENV_ID", help="e.g. HalfCheetah-v5 Ant-v5")
    check.add_argument("--seeds", type=int, default=3, help="number of seeds (0, 1, ...)")
    check.add_argument("--steps", type=int, default=1000, help="steps compared per seed")
    check.set_defaults(run=_cmd_check)

    bench = commands.add_parser("bench", help="run the benchmark suite (Markdown table and JSON)")
    bench.add_argument("--output", default="bench-results", help="folder of the Markdown and JSON results")
    bench.add_argument("--tiny", action="store_true", help="a smoke run with tiny sizes (no meaningful timings)")
    bench.add_argument(
        "--sections", nargs="*", default=None, help="subset of sections: tasks, collector, memory (default: all)"
    )
    bench.add_argument(
        "--threads", type=int, default=1, help="torch intra-op threads for the run (0: torch's default; default 1)"
    )
    bench.set_defaults(run=_cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``torchtasks`` command with ``argv`` (default: ``sys.argv[1:]``); return the exit code."""
    args = _parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
