"""Measure how exactly the Control Suite presets follow dm_control: the tables of docs/control_suite.md.

Run from the repository root, with the dm_control reference venv built (``make reference-venv``, or
``TORCHTASKS_DM_CONTROL_PYTHON`` naming a python that imports dm_control)::

    python docs/_scripts/control_suite_exactness.py --output docs/_generated

Two measurements per task, both with :mod:`torchtasks.envs.control_suite.check`:

- state by state (:func:`~torchtasks.envs.control_suite.check.compare_with_dm_control`): ``--envs`` envs,
  ``--steps`` random steps (actions up to 10 % beyond the bounds, partial resets every 25 steps), seeds
  0 .. ``--seeds``-1; dm_control steps from every state the preset was in. The largest absolute difference of the
  reward, of every observation entry (after a step, and at a reset), and of the next ``qpos``, ``qvel`` and ``act``,
  over all seeds;
- drift (:func:`~torchtasks.envs.control_suite.check.trajectory_drift`): ``--drift-envs`` envs, one free-running
  episode of ``--drift-steps`` steps per seed 0 .. ``--drift-seeds``-1 from the same start with the same random
  actions in the bounds, never resynchronised: the first control step at which the largest ``|qpos|`` difference
  exceeds 1e-9, 1e-6 and 1e-3, and the difference after the last step.

Writes ``control_suite_exactness.json`` (every number to 6 significant digits, the versions, the date, the command and
the load average),
``control_suite_exactness_table.md`` and ``control_suite_drift_table.md`` into ``--output``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import mujoco
import torch

from torchtasks.envs.control_suite import CONTROL_SUITE_TASKS, control_suite_record
from torchtasks.envs.control_suite.check import CHECK_TOLERANCE, compare_with_dm_control, trajectory_drift
from torchtasks.envs.control_suite.models import control_suite_model
from torchtasks.envs.control_suite.reference import DmControlReference

#: the drift thresholds of the table (``trajectory_drift``'s ``first_above``), with their labels
THRESHOLDS = {1e-9: "1e-9", 1e-6: "1e-6", 1e-3: "1e-3"}
#: steps at which the JSON keeps the drift (the whole curve is 1000 numbers per seed)
DRIFT_SAMPLES = (1, 10, 100, 250, 500, 1000)


def rounded(value: Any) -> Any:
    """Every float of ``value`` to 6 significant digits (a JSON of full-length floats reads like commit hashes)."""
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {key: rounded(item) for key, item in value.items()}
    if isinstance(value, list):
        return [rounded(item) for item in value]
    return value


def _number(value: float) -> str:
    return "0" if value == 0 else f"{value:.1e}"


def _exactness(reference: DmControlReference, name: str, args: argparse.Namespace) -> dict[str, Any]:
    """The largest differences of ``name`` over the seeds."""
    parts = [
        compare_with_dm_control(name, reference, num_envs=args.envs, steps=args.steps, seed=seed)
        for seed in range(args.seeds)
    ]
    record = control_suite_record(name)
    merged: dict[str, Any] = {"task": name, "envs": args.envs, "steps": args.steps, "seeds": list(range(args.seeds))}
    merged["activations"] = int(control_suite_model(record.domain, record.task).na)  # act is compared where > 0
    merged["states"] = sum(part["states"] for part in parts)
    merged["reward"] = max(part["reward"] for part in parts)
    for key in ("observation", "reset_observation", "physics"):
        merged[key] = {entry: max(part[key][entry] for part in parts) for entry in parts[0][key]}
    merged["worst"] = max(part["worst"] for part in parts)
    return merged


def _drift(reference: DmControlReference, name: str, args: argparse.Namespace) -> dict[str, Any]:
    """``trajectory_drift`` per seed, with the curve sampled at :data:`DRIFT_SAMPLES`."""
    seeds = []
    for seed in range(args.drift_seeds):
        drift = trajectory_drift(name, reference, num_envs=args.drift_envs, steps=args.drift_steps, seed=seed)
        curve = drift["qpos"]
        seeds.append(
            {
                "seed": seed,
                "first_above": {THRESHOLDS[threshold]: step for threshold, step in drift["first_above"].items()},
                "final": drift["final"],
                "at_step": {str(step): curve[step - 1] for step in DRIFT_SAMPLES if step <= len(curve)},
            }
        )
    return {"task": name, "envs": args.drift_envs, "steps": args.drift_steps, "seeds": seeds}


def exactness_table(rows: list[dict[str, Any]]) -> str:
    """The Markdown table of the state-by-state comparison: a row per task, the largest differences."""
    lines = [
        "| task | states | reward | observation (largest entry) | reset observation | next qpos | next qvel "
        "| next act |",
        "| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: |",
    ]
    for row in rows:
        entry, largest = max(row["observation"].items(), key=lambda item: item[1])
        physics = row["physics"]
        lines.append(
            f"| {row['task']} | {row['states']} | {_number(row['reward'])} | {_number(largest)} (`{entry}`) "
            f"| {_number(max(row['reset_observation'].values()))} | {_number(physics['qpos'])} "
            f"| {_number(physics['qvel'])} | {_number(physics['act']) if row['activations'] else '–'} |"
        )
    return "\n".join(lines) + "\n"


def drift_table(rows: list[dict[str, Any]]) -> str:
    """The Markdown table of the drift: a row per task, the first steps above each threshold and the last value."""
    seeds = "/".join(str(part["seed"]) for part in rows[0]["seeds"])
    header = " | ".join(f"first step > {label}" for label in THRESHOLDS.values())
    lines = [
        f"| task | {header} | after the last step |",
        "| --- | " + " | ".join("---:" for _ in THRESHOLDS) + " | ---: |",
    ]
    for row in rows:
        cells = [
            " / ".join(str(part["first_above"][label] or "never") for part in row["seeds"])
            for label in THRESHOLDS.values()
        ]
        final = " / ".join(_number(part["final"]) for part in row["seeds"])
        lines.append(f"| {row['task']} | {' | '.join(cells)} | {final} |")
    lines.append("")
    lines.append(f"Each cell: seed {seeds}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(CONTROL_SUITE_TASKS), metavar="TASK")
    parser.add_argument("--envs", type=int, default=4, help="envs of the state-by-state comparison")
    parser.add_argument("--steps", type=int, default=200, help="steps per seed of the state-by-state comparison")
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0 .. N-1 of the state-by-state comparison")
    parser.add_argument("--drift-envs", type=int, default=2)
    parser.add_argument("--drift-steps", type=int, default=1000)
    parser.add_argument("--drift-seeds", type=int, default=2)
    parser.add_argument("--output", default="runs/control_suite_exactness", help="folder of the results")
    args = parser.parse_args(argv)
    for name in args.tasks:
        control_suite_record(name)  # an unknown name fails before anything runs
    started = datetime.datetime.now(datetime.timezone.utc)
    clock_start = time.perf_counter()
    load_before = os.getloadavg()[0]
    exactness, drift = [], []
    with DmControlReference() as reference:
        versions = dict(reference.versions)
        for name in args.tasks:
            clock = time.perf_counter()
            exactness.append(_exactness(reference, name, args))
            drift.append(_drift(reference, name, args))
            print(
                f"{name}: largest difference {exactness[-1]['worst']:.1e}, "
                f"drift after {args.drift_steps} steps {max(s['final'] for s in drift[-1]['seeds']):.1e} "
                f"({time.perf_counter() - clock:.1f} s)",
                flush=True,
            )
    results = rounded(
        {
            "date": started.strftime("%Y-%m-%d %H:%M UTC"),
            "command": " ".join(["python", "docs/_scripts/control_suite_exactness.py", *(argv or sys.argv[1:])]),
            "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
            "seconds": time.perf_counter() - clock_start,
            "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
            "versions": {
                "torchtasks side": {
                    "python": platform.python_version(),
                    "torch": torch.__version__,
                    "mujoco": mujoco.__version__,
                },
                "dm_control side": versions,
            },
            "check_tolerance": CHECK_TOLERANCE,
            "exactness": exactness,
            "drift": drift,
        }
    )
    folder = Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "control_suite_exactness.json").write_text(json.dumps(results, indent=1) + "\n")
    (folder / "control_suite_exactness_table.md").write_text(exactness_table(results["exactness"]))
    (folder / "control_suite_drift_table.md").write_text(drift_table(results["drift"]))
    worst = max(row["worst"] for row in exactness)
    print(f"wrote {folder}/control_suite_exactness.json and the two tables; largest difference {worst:.1e}")
    return results


if __name__ == "__main__":
    main()
