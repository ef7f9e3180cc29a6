"""Run an example script as a user would, and check that it writes only under ``runs/<example name>/``.

Shared by ``tooling/test_examples.py`` and ``tooling/test_examples_training.py``;
``tooling/test_examples_write_under_runs.py`` checks that every example is run this way.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from repo_paths import ROOT

EXAMPLES = ROOT / "examples"


def _entries(folder: Path) -> set[str]:
    return {path.name for path in folder.iterdir()} if folder.is_dir() else set()


def run_quick(script: str, cwd: Path, *args: str, timeout: float) -> subprocess.CompletedProcess[str]:
    """Run ``examples/<script> --quick *args`` from ``cwd`` and check it wrote only under ``runs/<name>/``.

    ``cwd`` must hold nothing but (inputs in) ``runs/``. Fails with both output streams on a non-zero
    exit, and with the new entries if the script left anything in ``cwd`` outside ``runs/`` or in
    ``runs/`` outside ``runs/<script name without .py>/``, and with the lines of any Python warning it printed.
    """
    before = _entries(cwd)
    assert before <= {"runs"}, f"run {script} from an empty directory, not one holding {sorted(before)}"
    runs_before = _entries(cwd / "runs")
    command = [sys.executable, str(EXAMPLES / script), "--quick", *args]
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False)
    assert result.returncode == 0, (
        f"{' '.join(command)} exited with {result.returncode}\n"
        f"--- stdout ---\n{result.stdout}\n--- stderr ---\n{result.stderr}"
    )
    outside = sorted(_entries(cwd) - {"runs"})
    detail = ""
    if "MUJOCO_LOG.TXT" in outside:
        lines = (cwd / "MUJOCO_LOG.TXT").read_text(errors="replace").strip().splitlines()
        detail = f"\nMUJOCO_LOG.TXT starts with: {lines[0] if lines else '(empty)'}"
    assert not outside, f"{script} wrote {outside} into its current directory (outside runs/){detail}"
    stray = sorted(_entries(cwd / "runs") - runs_before - {Path(script).stem})
    assert not stray, f"{script} wrote {stray} into runs/ instead of runs/{Path(script).stem}/"
    assert "\r" not in result.stderr, f"{script} drew a progress bar into a file (bars are for terminals only)"
    warned = [line for line in result.stderr.splitlines() if re.search(r"\b\w*Warning: ", line)]
    assert not warned, f"{script} printed warnings (a user sees them as noise): {warned[:3]}"
    return result
