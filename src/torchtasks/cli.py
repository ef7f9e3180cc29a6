"""The ``torchtasks`` command: ``demo``, ``list``, ``check`` and ``bench``.

Every mistake in the arguments is reported on one line, before anything runs, naming the choice or option
meant when one is close and the valid choices otherwise (exit status 2, no traceback); an ``--output`` folder
is created before the run, or refused with the system's reason. A bare ``torchtasks`` prints the help and
exits with status 2 (nothing was run). The help, ``list`` and ``check``'s table fit
``WIDTH`` (100) columns; progress bars are drawn on a terminal only.
"""

from __future__ import annotations

import argparse
import ast
import functools
import importlib
import importlib.util
import inspect
import json
import os
import re
import shutil
import sys
import tempfile
import textwrap
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from torchtasks._did_you_mean import closest, did_you_mean

__all__ = [
    "CHECK_OUTPUT",
    "DEMO_OUTPUT",
    "PARITY_TOLERANCE",
    "QUICK_FOLDER",
    "WIDTH",
    "SuggestingParser",
    "catalogue",
    "main",
    "make_output_folder",
    "output_folder",
    "plain_text",
]

#: largest absolute reward difference to Gymnasium that ``torchtasks check`` accepts
PARITY_TOLERANCE = 1e-5

#: where ``torchtasks demo`` writes its files unless ``--output`` says otherwise (relative to the current folder;
#: a ``--quick`` run writes into its :data:`QUICK_FOLDER`)
DEMO_OUTPUT = "runs/demo"

#: the folder, inside a run's default output folder, of a ``--quick`` run (the demo's and the examples'): a smoke
#: run never overwrites a full run's results
QUICK_FOLDER = "quick"

#: where ``torchtasks check`` writes its JSON details unless ``--output`` says otherwise
CHECK_OUTPUT = "runs/check"

#: the widest line the command prints (``list``, ``check`` and the help)
WIDTH = 100

#: the sections of ``torchtasks list``: ``(module, what it holds)``, in the order printed
_SECTIONS = (
    ("torchtasks.rewards", "reward functions"),
    ("torchtasks.tasks", "tasks"),
    ("torchtasks.predefined", "task factories"),
    ("torchtasks.spaces", "boxes and env specs"),
    ("torchtasks.domain", "domain randomization: the fields an env varies per env, Pyrado's distributions"),
    ("torchtasks.transforms", "TorchRL transforms: the task, goals, curricula, levels, domains, run state"),
    ("torchtasks.stats", "statistics of collected episodes"),
    ("torchtasks.envs", "environments"),
)

#: names a section's module imports only on first access, from submodules that need an extra:
#: ``{module: (submodules, extra)}``; ``torchtasks list`` reads their descriptions from the source
_LAZY = {
    "torchtasks.envs": (
        (
            "torchtasks.envs.locomotion",
            "torchtasks.envs.batched_mujoco",
            "torchtasks.envs.mujoco_declaration",
            "torchtasks.envs.multi_objective",
            "torchtasks.envs.control_suite",
            "torchtasks.envs.velocity_tracking",
        ),
        "mujoco",
    )
}

#: the module and name of the Gymnasium ids that ``torchtasks check`` accepts (read from the source)
_ENV_IDS = ("torchtasks.envs.locomotion", "SUPPORTED_ENV_IDS")

#: the module and name of the MO-Gymnasium ids that ``torchtasks check`` compares with MO-Gymnasium (from the source)
_MO_ENV_IDS = ("torchtasks.envs.multi_objective", "MULTI_OBJECTIVE_ENV_IDS")

#: the module and name of the Control Suite's domains and tasks, compared with dm_control by ``torchtasks check``
_CONTROL_SUITE_TABLE = ("torchtasks.envs.control_suite.models", "_TASK_TABLE")

#: the module and name of the command that installs MO-Gymnasium, the reference of the MO ids (from the source)
_MO_INSTALL = ("torchtasks.parity", "MO_GYMNASIUM_INSTALL")


# ------------------------------------------------------------------------------------------- text
def plain_text(text: str) -> str:
    """``text`` without Sphinx roles, double backticks, Markdown code and emphasis; whitespace collapsed.

    Example:
        >>> plain_text("Base of :class:`ParallelTasks`: ``nn.Module``\\\\ s, see :meth:`T.f <a.T.f>` and :func:`~a.b`.")
        'Base of ParallelTasks: nn.Modules, see T.f and b.'
    """

    def role(match: re.Match[str]) -> str:
        target = match.group(1).strip()
        if "<" in target and target.endswith(">"):
            return target[: target.index("<")].strip()
        return target[1:].rsplit(".", 1)[-1] if target.startswith("~") else target

    text = text.replace("\\ ", "")  # reST's escaped space, as in ``nn.Module``\ s
    text = re.sub(r":[a-z]+(?::[a-z]+)?:`([^`]*)`", role, text)
    text = re.sub(r"``(.*?)``", r"\1", text)
    text = re.sub(r"`([^`]*)`", r"\1", text)
    text = re.sub(r"\*\*(.*?)\*\*", r"\1", text)
    return " ".join(text.split())


def _summary_of(doc: str | None) -> str:
    """The first sentence of a docstring's first paragraph, as plain text (``""`` when there is none)."""
    paragraph = plain_text(inspect.cleandoc(doc or "").split("\n\n")[0])
    return re.split(r"(?<=[.!?])\s+(?=[A-Z])", paragraph)[0]


# ------------------------------------------------------------------------------------------- list
def _summary(obj: object) -> str:
    # a class's own docstring: inspect.getdoc would inherit its base's (``tuple``'s "Built-in immutable sequence.")
    return _summary_of(obj.__dict__.get("__doc__") if inspect.isclass(obj) else inspect.getdoc(obj))


def _is_api(obj: object) -> bool:
    """Classes and functions are listed; constants (tuples, numbers, strings) are not."""
    return inspect.isclass(obj) or inspect.isroutine(obj)


def _source_file(module_name: str) -> Path | None:
    """The source file of a torchtasks module, found without importing it or its parent packages.

    (``importlib.util.find_spec("torchtasks.envs.locomotion")`` imports ``torchtasks.envs``, and with it torch
    and tensordict: seconds, for a command that only builds its parser.)
    """
    package, *parts = module_name.split(".")
    if package != "torchtasks":
        spec = importlib.util.find_spec(module_name)
        return None if spec is None or spec.origin is None else Path(spec.origin)
    folder = Path(__file__).resolve().parent.joinpath(*parts)
    for path in (folder.with_suffix(".py"), folder / "__init__.py"):
        if path.is_file():
            return path
    return None


@functools.cache
def _parse(module_name: str) -> ast.Module | None:
    """The syntax tree of a module's source (``None`` without one); each file is read and parsed once per process."""
    try:
        path = _source_file(module_name)
        return None if path is None else ast.parse(path.read_text(encoding="utf-8"))
    except (ImportError, AttributeError, OSError, SyntaxError, TypeError, ValueError):
        return None


@functools.cache
def _defined_and_imported(module_name: str) -> tuple[dict[str, str], dict[str, list[str]]] | None:
    """The summaries of the classes and functions defined in ``module_name``'s source, and the names it imports
    from torchtasks modules (``{module: [name, ...]}``); ``None`` without a source."""
    tree = _parse(module_name)
    if tree is None:
        return None
    summaries: dict[str, str] = {}
    imported: dict[str, list[str]] = {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            summaries[node.name] = _summary_of(ast.get_docstring(node, clean=False))
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("torchtasks"):
            for alias in node.names:
                imported.setdefault(node.module or "", []).append(alias.name)
    return summaries, imported


def _source_summaries(module_name: str, _seen: frozenset[str] = frozenset()) -> dict[str, str]:
    """Summaries of the classes and functions of ``module_name`` (and of the torchtasks names it imports),
    read from the source without importing it."""
    found = _defined_and_imported(module_name)
    if found is None or module_name in _seen:
        return {}
    defined, imported = found
    summaries = dict(defined)
    for source, names in imported.items():
        found_there = _source_summaries(source, _seen | {module_name})
        summaries.update({name: found_there[name] for name in names if name in found_there and name not in summaries})
    return summaries


def _source_constant(module_name: str, name: str) -> Any:
    """The literal value of the top-level assignment ``name`` in ``module_name``'s source (``None`` if none)."""
    tree = _parse(module_name)
    for node in tree.body if tree is not None else ():
        target = node.target if isinstance(node, ast.AnnAssign) else None
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
        if isinstance(target, ast.Name) and target.id == name and node.value is not None:  # type: ignore[union-attr]
            try:
                return ast.literal_eval(node.value)  # type: ignore[union-attr]
            except ValueError:
                return None
    return None


def _needs(extra: str) -> str:
    return f"[needs the '{extra}' extra]"


def catalogue() -> list[tuple[str, list[tuple[str, str]]]]:
    """Return ``[(module, [(name, one-line summary), ...]), ...]`` of the public classes and functions.

    Summaries are plain text (no Sphinx markup). Names that need an extra (the Gymnasium MuJoCo presets and
    the batched MuJoCo env of :mod:`torchtasks.envs`) are described from the source without importing the
    extra; their summary ends with ``[needs the 'mujoco' extra]`` when it is not installed.

    Example:
        >>> sections = dict(catalogue())
        >>> any(name == "QuadraticErrorReward" for name, _ in sections["torchtasks.rewards"])
        True
    """
    from torchtasks._optional import has_extra

    result = []
    for module_name, _ in _SECTIONS:
        module = importlib.import_module(module_name)
        lazy_modules, extra = _LAZY.get(module_name, ((), ""))
        lazy: dict[str, str] = {}
        for lazy_module in lazy_modules:
            lazy.update(_source_summaries(lazy_module))
        note = f" {_needs(extra)}" if lazy_modules and not has_extra(extra) else ""
        entries = []
        for name in module.__all__:
            if name in vars(module):
                if _is_api(vars(module)[name]):
                    entries.append((name, _summary(vars(module)[name])))
            elif name in lazy:  # imported on first access: described from the source, the extra is not imported
                entries.append((name, lazy[name] + note))
        result.append((module_name, entries))
    return result


def _cmd_list(args: argparse.Namespace) -> int:
    from torchtasks._optional import install_hint

    titles = dict(_SECTIONS)
    marks = [_needs(extra) for extra in sorted({extra for _, extra in _LAZY.values()})]
    sections = catalogue()
    lines = []
    for module_name, entries in sections:
        lines += ["", f"{module_name}: {titles[module_name]}"]
        width = min(max(len(name) for name, _ in entries), 30)
        for name, summary in entries:
            for mark in marks:  # the mark first, so that the summary can wrap
                if summary.endswith(" " + mark):
                    summary = f"{mark} {summary[: -len(mark) - 1]}"
            wrapped = textwrap.wrap(summary, WIDTH - 4 - width) or [""]
            if len(name) > width:  # a long name: the summary starts on the next line
                lines += [f"  {name}", " " * (width + 4) + wrapped[0]]
            else:
                lines.append(f"  {name:<{width}}  {wrapped[0]}")
            lines += [" " * (width + 4) + line for line in wrapped[1:]]
        if module_name == _ENV_IDS[0].rsplit(".", 1)[0]:
            env_ids = ", ".join(_source_constant(*_ENV_IDS) or ())
            mo_ids = ", ".join(_source_constant(*_MO_ENV_IDS) or ())
            for text in (
                f"(the Gymnasium ids of the MuJoCo presets: {env_ids})",
                f"(the MO-Gymnasium ids of the multi-objective presets: {mo_ids})",
                f"(the DeepMind Control Suite tasks: {', '.join(_control_suite_tasks())})",
            ):
                indents = {"initial_indent": "  ", "subsequent_indent": "   "}
                lines += textwrap.wrap(text, WIDTH, break_on_hyphens=False, **indents)  # ids stay whole
    print("\n".join(lines))
    summaries = [summary for _, entries in sections for _, summary in entries]
    for extra in sorted({extra for _, extra in _LAZY.values()}):
        if any(summary.endswith(_needs(extra)) for summary in summaries):
            print(f"\n{_needs(extra)}: install it with\n  {install_hint(extra)}")  # the command unwrapped
    return 0


# ------------------------------------------------------------------------------------------- demo
def output_folder(given: str | Path | None, default: str | Path, quick: bool) -> Path:
    """The folder a run writes into: ``given`` (its ``--output``), else ``default``, or ``default/quick`` for a
    ``--quick`` run (:data:`QUICK_FOLDER`). One rule for ``torchtasks demo`` and the example scripts.

    Example:
        >>> [str(output_folder(given, "runs/demo", quick)) for given, quick in ((None, 0), (None, 1), ("x", 1))]
        ['runs/demo', 'runs/demo/quick', 'x']
    """
    if given is not None:
        return Path(given)
    return Path(default) / QUICK_FOLDER if quick else Path(default)


def make_output_folder(folder: str | Path) -> str | None:
    """Create ``folder`` (parents included) and write a scratch file into it, before a run: None when that
    worked, else why not, on one line (``--output: cannot create '/proc/x': No such file or directory``).

    Checked by doing, not by ``os.access``, which grants root everything (``/proc`` included).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as root:
        ...     (make_output_folder(Path(root) / "a" / "b"), (Path(root) / "a" / "b").is_dir())
        (None, True)
        >>> make_output_folder("/dev/null/x")
        "--output: cannot create '/dev/null/x': Not a directory"
    """
    path = Path(folder).expanduser()
    if path.exists() and not path.is_dir():
        return f"--output: {str(folder)!r} exists and is not a folder"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        return f"--output: cannot create {str(folder)!r}: {_reason(error, path)}"
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as error:
        return f"--output: cannot write into {str(folder)!r}: {_reason(error, path)}"
    return None


def _reason(error: OSError, path: Path) -> str:
    """An OSError's reason on one line, naming the file it concerns when that is not ``path`` (a parent)."""
    reason = error.strerror or str(error)
    if error.filename is not None and Path(error.filename) != path:
        reason += f" ({error.filename})"
    return reason


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


# ------------------------------------------------------------------------------------------ check
def _usage_error(command: str, message: str) -> int:
    print(f"torchtasks {command}: {message}", file=sys.stderr)
    return 2


def _unknown_env(env_id: str, env_ids: Sequence[str]) -> str:
    by_lower = {name.lower(): name for name in env_ids}
    close = closest(env_id.lower(), list(by_lower), cutoff=_CHOICE_CUTOFF)
    if close:  # the one valid choice the user meant: a line that fits a terminal
        return f"unknown env {env_id!r}; did you mean {by_lower[close[0]]}?"
    return f"unknown env {env_id!r}; choose one of {', '.join(env_ids)}"


def _merge_gymnasium(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """One :func:`~torchtasks.parity.check_parity` result of several one-seed results (as with all seeds at once)."""
    row = dict(parts[0])
    row["seeds"] = [seed for part in parts for seed in part["seeds"]]
    for key in ("steps", "episodes", "termination_mismatches", "observation_mismatches", "seconds"):
        row[key] = sum(part[key] for part in parts)
    row["max_abs_reward_diff"] = max(part["max_abs_reward_diff"] for part in parts)
    row["max_abs_term_diff"] = {
        name: max(part["max_abs_term_diff"][name] for part in parts) for name in parts[0]["max_abs_term_diff"]
    }
    return row


def _merge_batched(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """One :func:`~torchtasks.parity.check_batched_parity` result of several one-seed results (the same merge)."""
    row = dict(parts[0])
    row["seeds"] = [seed for part in parts for seed in part["seeds"]]
    for key in ("steps", "transitions", "episodes", "terminated", "truncated", "forced_resets"):
        if key in row:
            row[key] = sum(part[key] for part in parts)
    row["partial_reset_problems"] = sum(part.get("partial_reset_problems", 0) for part in parts)
    row["seconds"] = sum(part["seconds"] for part in parts)
    for key in ("max_abs_diff", "max_abs_term_diff"):
        row[key] = {name: max(part[key][name] for part in parts) for name in parts[0][key]}
    row["first_mismatch"] = next((part["first_mismatch"] for part in parts if part.get("first_mismatch")), None)
    row["passed"] = all(part.get("passed", True) for part in parts)
    return row


def _number(value: float) -> str:
    return "0" if value == 0 else f"{value:.1e}"


def _seeds(seeds: Sequence[int]) -> str:
    """The seeds checked, as in the full table's column: ``0`` or a range ``0-2``."""
    seeds = sorted(seeds)
    if len(seeds) > 1 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return " ".join(str(seed) for seed in seeds)


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _gymnasium_table(rows: Sequence[dict[str, Any]]) -> str:
    header = ("env", "seeds", "steps", "episodes", "reward diff", "term diff", "flag mism.", "obs mism.", "result", "s")
    cells = [
        (
            row["env"],
            _seeds(row["seeds"]),
            str(row["steps"]),
            str(row["episodes"]),
            _number(row["max_abs_reward_diff"]),
            _number(max(row["max_abs_term_diff"].values(), default=0.0)),
            str(row["termination_mismatches"]),
            str(row["observation_mismatches"]),
            "PASS" if _gymnasium_passed(row) else "FAIL",
            f"{row['seconds']:.1f}",
        )
        for row in rows
    ]
    legend = (
        f"diff: largest |torchtasks - Gymnasium| (reward within {PARITY_TOLERANCE}; term: worst reward term);\n"
        "mism.: steps whose termination flags differ (flag) or whose observations are not bit-identical (obs)"
    )
    return _table(header, cells) + "\n" + legend


def _gymnasium_passed(row: dict[str, Any]) -> bool:
    return (
        row["max_abs_reward_diff"] <= PARITY_TOLERANCE
        and not row["termination_mismatches"]
        and not row["observation_mismatches"]
    )


def _batched_table(rows: Sequence[dict[str, Any]], passed: Callable[[dict[str, Any]], bool], tolerance: float) -> str:
    header = ("env", "envs", "seeds", "steps", "episodes", "resets", "obs", "reward", "term", "flag", "result", "s")
    cells = []
    for row in rows:
        differences, terms = row["max_abs_diff"], row["max_abs_term_diff"]
        flags = max(differences.get(key, 0.0) for key in ("terminated", "truncated"))
        cells.append(
            (
                row["env"],
                str(row.get("num_envs", "")),
                _seeds(row["seeds"]),
                str(row["steps"]),
                str(row.get("episodes", "")),
                str(row.get("forced_resets", "")),
                _number(differences["observation"]),
                _number(differences["reward"]),
                _number(max(terms.values(), default=0.0)),
                _number(flags),
                "PASS" if passed(row) else "FAIL",
                f"{row['seconds']:.1f}",
            )
        )
    legend = (
        f"obs, reward, term (worst reward term), flag (terminated, truncated): largest |batched - Gymnasium|,\n"
        f"each within {tolerance}; resets: partial resets forced mid-episode"
    )
    return _table(header, cells) + "\n" + legend


def _multi_objective_table(rows: Sequence[dict[str, Any]], passed: Callable[[dict[str, Any]], bool]) -> str:
    header = ("env", "backend", "envs", "seeds", "transitions", "resets", "vector mism.", "reward", "term", "obs")
    header += ("flag", "result", "s")
    cells = []
    for row in rows:
        differences = row["max_abs_diff"]
        cells.append(
            (
                row["env"],
                row["backend"],
                str(row["num_envs"]),
                _seeds(row["seeds"]),
                str(row["transitions"]),
                str(row["episodes"] + row["forced_resets"]),
                str(row["vector_reward_mismatches"]),
                _number(differences["reward"]),
                _number(max(row["max_abs_term_diff"].values(), default=0.0)),
                _number(differences["observation"]),
                _number(max(differences[key] for key in ("terminated", "truncated", "done"))),
                "PASS" if passed(row) else "FAIL",
                f"{row['seconds']:.1f}",
            )
        )
    legend = (
        "vector mism.: transitions whose vector reward is not MO-Gymnasium's bit for bit; reward (against\n"
        "Gymnasium's terms' sum), term, obs, flag: largest |torchtasks - MO-Gymnasium|; resets: ended or forced"
    )
    return _table(header, cells) + "\n" + legend


def _write_details(folder: Path, backend: str, rows: list[dict[str, Any]], markdown: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"check_{backend}_{time.strftime('%Y%m%d-%H%M%S')}.json"
    details = {"backend": backend, "rows": rows, "table": markdown.splitlines()}
    path.write_text(json.dumps(details, indent=2, default=str) + "\n", encoding="utf-8")
    return path


def _control_suite_tasks() -> tuple[str, ...]:
    """The Control Suite's ``domain-task`` names (read from the source: no MuJoCo import)."""
    table = _source_constant(*_CONTROL_SUITE_TABLE) or {}
    return tuple(f"{domain}-{task}" for domain, tasks in table.items() for task in tasks)


def _check_refusal(args: argparse.Namespace) -> str | None:
    """Why ``torchtasks check``'s arguments cannot run (an unknown env id, ids of both kinds, ...), or None."""
    gymnasium_ids, mo_ids = _source_constant(*_ENV_IDS) or (), _source_constant(*_MO_ENV_IDS) or ()
    suite = _control_suite_tasks()
    known = (*gymnasium_ids, *mo_ids, *suite)
    unknown = [env_id for env_id in args.env_ids if known and env_id not in known]
    if unknown:  # the closest of all, or the Gymnasium ids listed and the other kinds named
        message = _unknown_env(unknown[0], known)
        if "did you mean" not in message:
            message = _unknown_env(unknown[0], gymnasium_ids) + ", an MO-Gymnasium id or a Control Suite task"
        return message
    control_suite = [env_id for env_id in args.env_ids if env_id in suite]
    if control_suite and len(control_suite) < len(args.env_ids):
        return "check Control Suite tasks (walker-walk, ...) and Gymnasium ids in separate commands"
    if args.envs is not None and args.backend != "batched" and not control_suite:
        return "--envs applies to --backend batched and to Control Suite tasks only"
    multi_objective = [env_id for env_id in args.env_ids if env_id in mo_ids]
    if multi_objective and len(multi_objective) < len(args.env_ids):
        return "check MO-Gymnasium ids (mo-...) and Gymnasium ids in separate commands"
    return None


def _control_suite_table(rows: Sequence[dict[str, Any]], tolerance: float) -> str:
    header = ("task", "seeds", "envs", "states", "reward", "obs", "reset obs", "physics", "drift", "result", "s")
    cells = [
        (
            row["task"],
            _seeds(row["seeds"]),
            str(row["envs"]),
            str(row["states"]),
            _number(row["reward"]),
            _number(max(row["observation"].values())),
            _number(max(row["reset_observation"].values())),
            _number(max(row["physics"].values())),
            _number(row["drift"]),
            "PASS" if row["worst"] <= tolerance else "FAIL",
            f"{row['seconds']:.1f}",
        )
        for row in rows
    ]
    legend = (
        "largest |torchtasks - dm_control| over every step of every env, from the same states: reward, obs\n"
        "(every entry), reset obs, physics (next qpos, qvel, act); drift: largest qpos difference after\n"
        f"--steps steps of one free-running episode (not checked). PASS: every difference <= {tolerance:g}"
    )
    return _table(header, cells) + "\n" + legend


def _check_control_suite(args: argparse.Namespace) -> int:
    """``torchtasks check walker-walk``: the Control Suite presets against dm_control in its reference venv."""
    from tqdm import tqdm

    from torchtasks.envs.control_suite import check
    from torchtasks.envs.control_suite.reference import DmControlReference, DmControlUnavailableError

    try:
        reference = DmControlReference()
    except DmControlUnavailableError as error:
        return _usage_error("check", str(error))
    names = list(dict.fromkeys(args.env_ids))
    num_envs = 4 if args.envs is None else args.envs
    rows = []
    disable = True if args.no_progress else None  # None: shown on a terminal only
    total = len(names) * (args.seeds + 1) * args.steps
    with reference, tqdm(total=total, desc="torchtasks check", unit="step", file=sys.stderr, disable=disable) as bar:
        for name in names:
            start = time.perf_counter()
            parts = []
            for seed in range(args.seeds):
                bar.set_postfix_str(f"{name}, seed {seed}")
                parts.append(
                    check.compare_with_dm_control(name, reference, num_envs=num_envs, steps=args.steps, seed=seed)
                )
                bar.update(args.steps)
            bar.set_postfix_str(f"{name}, drift")
            drift = check.trajectory_drift(name, reference, num_envs=1, steps=args.steps, seed=0)
            bar.update(args.steps)
            row = dict(parts[0])
            row["seeds"] = list(range(args.seeds))
            row["states"] = sum(part["states"] for part in parts)
            row["reward"] = max(part["reward"] for part in parts)
            row["worst"] = max(part["worst"] for part in parts)
            for key in ("observation", "reset_observation", "physics"):
                row[key] = {entry: max(part[key][entry] for part in parts) for entry in parts[0][key]}
            row["drift"], row["drift_first_above"] = drift["final"], drift["first_above"]
            row["seconds"] = time.perf_counter() - start
            rows.append(row)
    markdown = _control_suite_table(rows, check.CHECK_TOLERANCE)
    print(markdown)
    path = _write_details(Path(args.output), "control_suite", rows, markdown)
    print(f"wrote {path} (the details: every entry and the drift)")
    failed = [row["task"] for row in rows if not check.passed(row)]
    if failed:
        print(
            f"dm_control parity NOT met (tolerance {check.CHECK_TOLERANCE:g}) for: {', '.join(failed)}", file=sys.stderr
        )
    return 1 if failed else 0


def _cmd_check(args: argparse.Namespace) -> int:
    if any(env_id in _control_suite_tasks() for env_id in args.env_ids):
        try:
            return _check_control_suite(args)
        except ImportError as error:  # pragma: no cover - depends on the optional mujoco extra
            from torchtasks._optional import missing_extra

            print(
                f"{missing_extra('mujoco', 'torchtasks check')} (cannot import {error.name or error})", file=sys.stderr
            )
            return 2
    mo_ids = _source_constant(*_MO_ENV_IDS) or ()
    multi_objective = [env_id for env_id in args.env_ids if env_id in mo_ids]
    try:
        from torchtasks import parity
    except ImportError as error:  # pragma: no cover - depends on the optional mujoco extra
        from torchtasks._optional import missing_extra

        print(f"{missing_extra('mujoco', 'torchtasks check')} (cannot import {error.name or error})", file=sys.stderr)
        return 2
    if multi_objective:
        try:
            importlib.import_module("mo_gymnasium")
        except ImportError:
            install = _source_constant(*_MO_INSTALL)
            reference = "MO-Gymnasium 1.3.2 (a reference, not a dependency of torchtasks)"
            return _usage_error("check", f"{multi_objective[0]} is compared with {reference}: {install}")
        return _check_multi_objective(args, parity)
    from tqdm import tqdm

    env_ids = list(dict.fromkeys(args.env_ids))
    seeds = range(args.seeds)
    batched = args.backend == "batched"
    rows = []
    with tqdm(
        total=len(env_ids) * len(seeds) * args.steps,
        desc="torchtasks check",
        unit="step",
        file=sys.stderr,
        disable=True if args.no_progress else None,  # None: shown on a terminal only
    ) as progress:
        for env_id in env_ids:
            parts = []
            for seed in seeds:
                progress.set_postfix_str(f"{env_id}, seed {seed}")
                if batched:
                    num_envs = 3 if args.envs is None else args.envs
                    part = parity.check_batched_parity(env_id, seeds=[seed], steps=args.steps, num_envs=num_envs)
                else:
                    part = parity.check_parity(env_id, seeds=[seed], steps=args.steps)
                parts.append(part)
                progress.update(args.steps)
            rows.append(_merge_batched(parts) if batched else _merge_gymnasium(parts))
    compact = args.table == "compact"
    if batched:
        tolerance = parity.BATCHED_PARITY_TOLERANCE
        markdown = parity.format_batched_parity_table(rows)
        print(_batched_table(rows, parity.batched_parity_passed, tolerance) if compact else markdown)
        failed = [row["env"] for row in rows if not parity.batched_parity_passed(row)]
    else:
        markdown = parity.format_parity_table(rows)
        print(_gymnasium_table(rows) if compact else markdown)
        failed = [row["env"] for row in rows if not _gymnasium_passed(row)]
    path = _write_details(Path(args.output), args.backend, rows, markdown)
    print(f"wrote {path} (the details: every term, flag and count)")
    if batched:
        for row in rows:
            if row["env"] in failed:
                mismatch = row.get("first_mismatch") or "a partial reset disturbed another env"
                print(f"{row['env']}: FAIL, first difference above the tolerance: {mismatch}", file=sys.stderr)
        if failed:
            print(f"batched parity NOT met (tolerance {tolerance}) for: {', '.join(failed)}", file=sys.stderr)
    elif failed:
        print(f"parity NOT met (reward tolerance {PARITY_TOLERANCE}) for: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


def _check_multi_objective(args: argparse.Namespace, parity: Any) -> int:
    """``torchtasks check mo-...``: the multi-objective presets against MO-Gymnasium (imported by the caller)."""
    from tqdm import tqdm

    env_ids = list(dict.fromkeys(args.env_ids))
    num_envs = (3 if args.envs is None else args.envs) if args.backend == "batched" else 1
    rows = []
    disable = True if args.no_progress else None  # None: shown on a terminal only
    total = len(env_ids) * args.seeds * args.steps
    with tqdm(total=total, desc="torchtasks check", unit="step", file=sys.stderr, disable=disable) as progress:
        for env_id in env_ids:
            progress.set_postfix_str(env_id)
            rows.append(
                parity.check_multi_objective_parity(
                    env_id, seeds=range(args.seeds), steps=args.steps, backend=args.backend, num_envs=num_envs
                )
            )
            progress.update(args.seeds * args.steps)
    markdown = parity.format_multi_objective_parity_table(rows)
    passed = parity.multi_objective_parity_passed
    print(_multi_objective_table(rows, passed) if args.table == "compact" else markdown)
    path = _write_details(Path(args.output), f"multi_objective_{args.backend}", rows, markdown)
    print(f"wrote {path} (the details: every term, flag and count)")
    failed = [row["env"] for row in rows if not passed(row)]
    for row in rows:
        if row["env"] in failed and row["first_mismatch"]:
            print(f"{row['env']}: FAIL, first difference: {row['first_mismatch']}", file=sys.stderr)
    if failed:
        print(f"MO-Gymnasium parity NOT met for: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


# ------------------------------------------------------------------------------------------ bench
def _cmd_bench(args: argparse.Namespace) -> int:
    from torchtasks.bench import run_benchmarks

    run_benchmarks(output_dir=Path(args.output), tiny=args.tiny, sections=args.sections, threads=args.threads or None)
    return 0


# ----------------------------------------------------------------------------------------- parser
#: how close a command or env id must be to be suggested (an id of 9 letters written in 7 still finds its match)
_CHOICE_CUTOFF = 0.6


def _suggest(message: str) -> str:
    """argparse's ``invalid choice: 'chek' (choose from ...)`` as ``invalid choice: 'chek'; did you mean 'check'?``
    when one choice is close (the whole list otherwise)."""
    match = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)$", message)
    if match is None:
        return message
    choices = re.findall(r"'([^']*)'", match.group(2))
    hint = did_you_mean(match.group(1), choices, cutoff=_CHOICE_CUTOFF)
    if not hint:
        return message
    return f"{message[: match.start()]}invalid choice: {match.group(1)!r}{hint}"


def _unrecognized(parser: argparse.ArgumentParser, extras: Sequence[str]) -> str:
    """``unrecognized arguments: --quik; did you mean '--quick'?``: argparse's message, with the options of
    ``parser`` meant by the unknown ones that are close to one, in their order (``--quik=3`` is compared as
    ``--quik``)."""
    options = [option for option in parser._option_string_actions if option.startswith("--")]
    meant = {}
    for token in extras:
        name = token.split("=", 1)[0]
        if name.startswith("-") and len(name) > 1 and (close := closest(name, options)):
            meant[name] = close[0]
    message = f"unrecognized arguments: {' '.join(extras)}"
    if len(meant) == 1:
        return message + did_you_mean(*meant, options)
    listed = [repr(option) for option in meant.values()]  # in the order of the unknown ones
    return message + (f"; did you mean {', '.join(listed[:-1])} and {listed[-1]}?" if meant else "")


class SuggestingParser(argparse.ArgumentParser):
    """An ``argparse.ArgumentParser`` whose errors name the option or choice meant when one is close: ``--quik``
    gets ``did you mean '--quick'?``, a misspelt choice the choice (the whole list when none is close).

    The parser of the ``torchtasks`` command and of the example scripts. Abbreviations of options work as in
    argparse (``--qui`` is ``--quick``; an ambiguous one lists the options it could be).

    Example:
        >>> import contextlib, io
        >>> parser = SuggestingParser(prog="demo")
        >>> _ = parser.add_argument("--quick", action="store_true")
        >>> with contextlib.redirect_stderr(io.StringIO()) as err, contextlib.suppress(SystemExit):
        ...     _ = parser.parse_args(["--quik"])
        >>> err.getvalue().splitlines()[-1]
        "demo: error: unrecognized arguments: --quik; did you mean '--quick'?"
    """

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            self.error(_unrecognized(self, extras))
        return namespace

    def error(self, message: str) -> NoReturn:
        super().error(_suggest(message))


class _Parser(SuggestingParser):
    """An argument parser whose errors are one line: ``torchtasks check: argument --seeds: ...``."""

    def error(self, message: str) -> NoReturn:
        message = _suggest(message)
        line = f"{self.prog}: {message.replace('argument COMMAND: ', '')}"
        hint = f" (see '{self.prog} --help')"
        self.exit(2, line + (hint if len(line + hint) <= WIDTH else "") + "\n")


def _formatter(prog: str) -> argparse.HelpFormatter:
    return argparse.HelpFormatter(prog, width=min(shutil.get_terminal_size().columns, WIDTH), max_help_position=24)


def _count(minimum: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return value

    return parse


SEED_MAX = 2**63 - 1  # torch's generators take a signed 64-bit seed


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"expected an integer from 0 to 2**63 - 1, got {text!r}")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="torchtasks",
        description="Batched, differentiable tasks for TorchRL.",
        epilog="'torchtasks COMMAND --help' describes a command's options.",
        formatter_class=_formatter,
    )
    from torchtasks import __version__

    parser.add_argument("--version", action="version", version=f"torchtasks {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def command(name: str, help: str, description: str) -> argparse.ArgumentParser:
        return commands.add_parser(name, help=help, description=description, formatter_class=_formatter)

    demo = command(
        "demo",
        "run a task chain inside a TorchRL Collector and summarise it",
        "A swing-up task on 64 batched torch pendulums inside a TorchRL Collector; prints its rewards, "
        "successes and frames per second and writes the curves (JSON) and a plot (PNG).",
    )
    demo.add_argument("--quick", action="store_true", help="a short run: 64 000 frames instead of 320 000")
    demo.add_argument(
        "--output",
        default=None,
        metavar="DIR",
        help=f"folder of the JSON and PNG (default: {DEMO_OUTPUT}; {Path(DEMO_OUTPUT) / QUICK_FOLDER} with --quick)",
    )
    demo.add_argument("--seed", type=_seed, default=0, metavar="N", help="random seed (default: %(default)s)")
    demo.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    demo.set_defaults(run=_cmd_demo)

    listing = command(
        "list",
        "list the classes and functions of torchtasks, by module",
        "Every public class and function of torchtasks, by module, with its one-line summary.",
    )
    listing.set_defaults(run=_cmd_list)

    check = command(
        "check",
        "compare a preset with Gymnasium or dm_control, step by step",
        "Compare presets with Gymnasium, MO-Gymnasium or dm_control (`make reference-venv`) for --seeds seeds "
        "of --steps random steps; exit 1 when they differ.",
    )
    env_ids = ", ".join(_source_constant(*_ENV_IDS) or ("HalfCheetah-v5", "Ant-v5"))
    mo_id = (_source_constant(*_MO_ENV_IDS) or ("mo-hopper-v5",))[0]
    check.add_argument(
        "env_ids",
        nargs="+",
        metavar="ENV_ID",
        help=f"one or more of {env_ids}, MO-Gymnasium's ({mo_id}, ...), Control Suite tasks (walker-walk)",
    )
    check.add_argument(
        "--seeds", type=_count(1), default=3, metavar="N", help="seeds 0, ..., N-1 (default: %(default)s)"
    )
    check.add_argument(
        "--steps",
        type=_count(1),
        default=1000,
        metavar="N",
        help="steps per seed (the table counts all seeds' steps) (default: %(default)s)",
    )
    check.add_argument(
        "--backend",
        choices=("gymnasium", "batched"),
        default="gymnasium",
        help=f"gymnasium: one Gymnasium env in TorchRL, reward within {PARITY_TOLERANCE}; batched: "
        "BatchedMujocoEnv against a Gymnasium env per entry, partial resets forced (obs, reward, terms, flags "
        "within 1e-9) (default: %(default)s)",
    )
    check.add_argument(
        "--envs",
        type=_count(1),
        default=None,
        metavar="N",
        help="envs of the batched env (default: 3; Control Suite tasks: 4)",
    )
    check.add_argument(
        "--output", default=CHECK_OUTPUT, metavar="DIR", help="folder of the JSON details (default: %(default)s)"
    )
    check.add_argument(
        "--table",
        choices=("compact", "full"),
        default="compact",
        help="compact (100 columns) or full (a column per reward term) (default: %(default)s)",
    )
    check.add_argument("--no-progress", action="store_true", help="hide the progress bar (shown on a terminal)")
    check.set_defaults(run=_cmd_check, refuse=_check_refusal)

    bench = command(
        "bench",
        "run the benchmark suite (Markdown table and JSON)",
        "Time task evaluation, a Collector run and task memory; write benchmarks.md and benchmarks.json.",
    )
    bench.add_argument(
        "--output", default="runs/bench", metavar="DIR", help="folder of the Markdown and JSON (default: %(default)s)"
    )
    bench.add_argument("--tiny", action="store_true", help="a smoke run with tiny sizes (no meaningful timings)")
    bench.add_argument(
        "--sections",
        nargs="*",
        choices=("tasks", "collector", "memory"),
        default=None,
        metavar="SECTION",
        help="any of tasks, collector, memory (default: all)",
    )
    bench.add_argument(
        "--threads",
        type=_count(0),
        default=1,
        metavar="N",
        help="torch threads, 0: torch's default (default: %(default)s)",
    )
    bench.set_defaults(run=_cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``torchtasks`` command with ``argv`` (default: ``sys.argv[1:]``); return the exit code.

    A bare ``torchtasks`` prints the help and returns 2; a mistake in the arguments exits with status 2
    after one line on stderr.
    """
    parser = _parser()
    args, unknown = parser.parse_known_args(argv)
    commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    if unknown:  # reported by the subcommand's parser, whose options the user meant
        command_parser = commands.choices.get(args.command, parser)
        command_parser.error(_unrecognized(command_parser, unknown))
    if args.command is None:
        parser.print_help()
        return 2
    refusal = args.refuse(args) if "refuse" in args else None  # checks that need no import, before any folder
    if refusal is not None:
        return _usage_error(args.command, refusal)
    if args.command == "demo":
        args.output = output_folder(args.output, DEMO_OUTPUT, args.quick)
    problem = make_output_folder(args.output) if getattr(args, "output", None) is not None else None
    if problem is not None:
        commands.choices[args.command].error(problem)
    try:
        return args.run(args)
    except BrokenPipeError:  # e.g. `torchtasks list | head`: stop quietly, as other commands do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes
        return 141  # 128 + SIGPIPE, the shell's status of a command killed by a closed pipe


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
