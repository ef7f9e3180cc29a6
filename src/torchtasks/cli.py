"""The ``torchtasks`` command: ``demo``, ``list``, ``check`` and ``bench``."""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import inspect
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["DEMO_OUTPUT", "PARITY_TOLERANCE", "catalogue", "main"]

#: largest absolute reward difference to Gymnasium that ``torchtasks check`` accepts
PARITY_TOLERANCE = 1e-5

#: where ``torchtasks demo`` writes its files unless ``--output`` says otherwise (relative to the current folder)
DEMO_OUTPUT = "runs/demo"

_SECTIONS = (
    ("Reward functions", "torchtasks.rewards"),
    ("Tasks", "torchtasks.tasks"),
    ("Factories", "torchtasks.predefined"),
    ("Environments and presets", "torchtasks.envs"),
)


#: names a section's module imports only on first access, from a submodule that needs an extra:
#: ``{module: (submodule, extra)}``; ``torchtasks list`` reads their descriptions from the source
_LAZY = {"torchtasks.envs": ("torchtasks.envs.locomotion", "mujoco")}


def _summary(obj: object) -> str:
    doc = inspect.getdoc(obj) or ""
    return _first_line(doc)


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else "(no description)"


def _source_summaries(module_name: str) -> dict[str, str]:
    """One-line descriptions of the top-level names of ``module_name``, read from its source without importing it.

    Functions and classes: the docstring's first line; a tuple of strings: its ``#:`` comment and its items.
    """
    try:
        spec = importlib.util.find_spec(module_name)
        source = Path(spec.origin).read_text(encoding="utf-8")  # type: ignore[union-attr, arg-type]
        tree = ast.parse(source)
    except (ImportError, AttributeError, OSError, SyntaxError, TypeError, ValueError):
        return {}
    lines = source.splitlines()
    summaries: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            summaries[node.name] = _first_line(ast.get_docstring(node) or "")
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value is not None:
            comment = lines[node.lineno - 2].strip() if node.lineno >= 2 else ""
            comment = comment[2:].strip() if comment.startswith("#:") else ""
            try:
                value = ast.literal_eval(node.value)
            except ValueError:
                continue
            if isinstance(value, tuple) and all(isinstance(item, str) for item in value):
                summaries[node.target.id] = f"{comment}: {', '.join(value)}" if comment else ", ".join(value)
    return summaries


def catalogue() -> list[tuple[str, list[tuple[str, str]]]]:
    """Return ``[(section, [(name, one-line description), ...]), ...]`` of the public API.

    Names that need an extra (the Gymnasium MuJoCo presets of :mod:`torchtasks.envs`) are listed without
    importing it; their description ends with ``[needs the 'mujoco' extra]`` when it is not installed.

    Example:
        >>> sections = dict(catalogue())
        >>> any(name == "QuadraticErrorReward" for name, _ in sections["Reward functions"])
        True
    """
    from torchtasks._optional import has_extra

    result = []
    for title, module_name in _SECTIONS:
        module = importlib.import_module(module_name)
        lazy_module, extra = _LAZY.get(module_name, (None, ""))
        lazy = _source_summaries(lazy_module) if lazy_module else {}
        note = "" if not lazy_module or has_extra(extra) else f" {_needs(extra)}"
        entries = []
        for name in module.__all__:
            if name in vars(module):
                entries.append((name, _summary(vars(module)[name])))
            else:  # imported on first access: describe it from the source, do not import the extra
                entries.append((name, lazy.get(name, "(no description)") + note))
        result.append((title, entries))
    return result


def _needs(extra: str) -> str:
    return f"[needs the '{extra}' extra]"


def _cmd_list(args: argparse.Namespace) -> int:
    from torchtasks._optional import install_hint

    sections = catalogue()
    for title, entries in sections:
        print(f"\n{title}")
        width = max(len(name) for name, _ in entries)
        for name, summary in entries:
            print(f"  {name:<{width}}  {summary}")
    summaries = [summary for _, entries in sections for _, summary in entries]
    for extra in sorted({extra for _, extra in _LAZY.values()}):
        if any(summary.endswith(_needs(extra)) for summary in summaries):
            print(f"\n{_needs(extra)}: {install_hint(extra)}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from torchtasks.demo import format_result, run_demo

    frames, frames_per_batch = (64_000, 1_600) if args.quick else (320_000, 3_200)
    print("torchtasks demo: a swing-up task on 64 batched torch pendulums inside a TorchRL Collector;")
    print("a classical controller acts (its action noise decays over the run), the task decides rewards,")
    print("successes and episode ends.")
    result = run_demo(
        total_frames=frames,
        frames_per_batch=frames_per_batch,
        output_dir=args.output,
        progress=not args.no_progress,
        seed=args.seed,
    )
    print(format_result(result))
    for path, what in ((result.metrics_path, "per-batch curves and summary"), (result.plot_path, "plot")):
        if path is not None:
            print(f"wrote {path} ({what})")
    if result.plot_note:
        print(result.plot_note)
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    if args.envs is not None and args.backend != "batched":
        print("torchtasks check: --envs applies to --backend batched only", file=sys.stderr)
        return 2
    try:
        from torchtasks import parity
    except ImportError as error:  # pragma: no cover - depends on the optional mujoco extra
        from torchtasks._optional import missing_extra

        print(f"{missing_extra('mujoco', 'torchtasks check')} (cannot import {error.name or error})", file=sys.stderr)
        return 2
    env_ids = args.env_ids
    seeds = tuple(range(args.seeds))
    if args.backend == "batched":
        num_envs = 3 if args.envs is None else args.envs
        rows = [
            parity.check_batched_parity(env_id, seeds=seeds, steps=args.steps, num_envs=num_envs) for env_id in env_ids
        ]
        print(parity.format_batched_parity_table(rows))
        failed = [row for row in rows if not parity.batched_parity_passed(row)]
        for row in failed:
            print(f"{row['env']}: FAIL, first difference above the tolerance: {row['first_mismatch']}", file=sys.stderr)
        if failed:
            names = ", ".join(row["env"] for row in failed)
            print(f"batched parity NOT met (tolerance {parity.BATCHED_PARITY_TOLERANCE}) for: {names}", file=sys.stderr)
        return 1 if failed else 0
    rows = [parity.check_parity(env_id, seeds=seeds, steps=args.steps) for env_id in env_ids]
    print(parity.format_parity_table(rows))
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
    demo.add_argument(
        "--output", default=DEMO_OUTPUT, help=f"folder of the JSON curves and the PNG plot (default: {DEMO_OUTPUT}/)"
    )
    demo.add_argument("--seed", type=int, default=0, help="random seed")
    demo.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    demo.set_defaults(run=_cmd_demo)

    listing = commands.add_parser("list", help="list reward functions, tasks, factories and presets")
    listing.set_defaults(run=_cmd_list)

    check = commands.add_parser("check", help="compare a Gymnasium MuJoCo preset with Gymnasium, step by step")
    check.add_argument("env_ids", nargs="+", metavar="ENV_ID", help="e.g. HalfCheetah-v5 Ant-v5")
    check.add_argument("--seeds", type=int, default=3, help="number of seeds (0, 1, ...)")
    check.add_argument("--steps", type=int, default=1000, help="steps compared per seed")
    check.add_argument(
        "--backend",
        choices=("gymnasium", "batched"),
        default="gymnasium",
        help="the preset's backend (default: %(default)s): 'gymnasium' (one Gymnasium env in TorchRL; reward "
        f"within {PARITY_TOLERANCE}) or 'batched' (BatchedMujocoEnv against one Gymnasium env per batch entry, "
        "states synchronised after every reset, partial resets forced mid-episode; observation, reward, terms "
        "and flags within 1e-9)",
    )
    check.add_argument(
        "--envs", type=int, default=None, help="envs of the batched env (--backend batched only; default 3)"
    )
    check.set_defaults(run=_cmd_check)

    bench = commands.add_parser("bench", help="run the benchmark suite (Markdown table and JSON)")
    bench.add_argument("--output", default="runs/bench", help="folder of the Markdown and JSON results")
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
