"""Run an example script as a user would, and check that it writes only under ``runs/<example name>/``.

Shared by ``tooling/test_examples.py`` and ``tooling/test_examples_training.py``;
``tooling/test_examples_write_under_runs.py`` checks that every example is run this way.

A fresh interpreter per run spends ~5-8 s of CPU importing torch, TorchRL, torchtasks (and MuJoCo) before the
script's first line, most of a quick run. So the runs start from one interpreter per test process that has
imported those modules and nothing else (:data:`PRELOADED`) and forks a child per run, as Python's
``forkserver`` start method does: the child changes to the run's directory, takes ``/dev/null`` as stdin and
files as stdout and stderr, and runs the script as ``__main__`` with ``sys.argv = [script, ...]`` and the
scripts' folder first on ``sys.path``, as ``python examples/<script>`` does. Whatever those imports print goes
into every run's stderr, so a warning at import time still fails the run. The server refuses to fork if the
imports left a Python thread running (a forked child would inherit its locks, not the thread); torch's own
native thread is fork-safe (its ``DataLoader`` workers are forked from interpreters that imported torch).
:func:`run_quick` with ``fresh=True`` starts a fresh interpreter instead (the Ray example: Ray's client must not
be forked).
"""

from __future__ import annotations

import atexit
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from repo_paths import ROOT

EXAMPLES = ROOT / "examples"

#: the modules the fork server imports before it forks: what every example imports first, MuJoCo's, and the
#: plotting module of the examples that draw their curves (each of these imports matplotlib.pyplot: ~0.8 s)
PRELOADED = (
    "matplotlib.pyplot",
    "torch",
    "tensordict",
    "tensordict.nn",
    "torchrl.collectors",
    "torchrl.envs",
    "torchrl.modules",
    "torchrl.objectives",
    "torchrl.objectives.value",
    "torchtasks",
    "torchtasks.envs",
    "torchtasks.rewards",
    "torchtasks.stats",
    "torchtasks.tasks",
    "torchtasks.transforms",
    "torchtasks.envs.locomotion",
)

#: the fork server (``python -c SERVER``): imports :data:`PRELOADED`, says ``ready``, then per request line
#: ``<cwd>\0<stdout file>\0<stderr file>\0<script>\0<arg>...`` forks a child that runs the script and answers with
#: the child's pid, then, once it ended, its exit status
SERVER = r"""
import importlib, os, sys, threading
for name in sys.argv[1:]:
    importlib.import_module(name)
if threading.active_count() != 1:
    sys.exit(f"the preloaded modules left threads running, which a fork would not copy: {threading.enumerate()}")
print("ready", flush=True)
for line in sys.stdin:
    cwd, stdout, stderr, script, *args = line.rstrip("\n").split("\0")
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        os.chdir(cwd)
        appended = os.O_WRONLY | os.O_APPEND
        for fd, path, flags in ((0, os.devnull, os.O_RDONLY), (1, stdout, appended), (2, stderr, appended)):
            opened = os.open(path, flags)
            os.dup2(opened, fd)
            os.close(opened)
        sys.argv = [script, *args]
        sys.path[0] = os.path.dirname(script)
        import runpy

        try:
            runpy.run_path(script, run_name="__main__")
        except SystemExit:
            raise
        except BaseException:
            import traceback

            traceback.print_exc()
            sys.exit(1)
        sys.exit(0)
    print(pid, flush=True)
    _, status = os.waitpid(pid, 0)
    print(os.waitstatus_to_exitcode(status), flush=True)
"""


class _ForkServer:
    """The running fork server of this test process (started at the first run, stopped at exit)."""

    def __init__(self) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix="example_runs_"))
        self.imports_output = self.folder / "imports_stderr.txt"
        with self.imports_output.open("w") as stderr:
            self.process = subprocess.Popen(
                [sys.executable, "-c", SERVER, *PRELOADED],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=stderr,
                text=True,
            )
        self._pending = ""
        atexit.register(self.stop)
        assert self._line(timeout=300) == "ready", f"the example fork server failed:\n{self.imports_output.read_text()}"

    def _line(self, timeout: float) -> str | None:
        """The server's next answer, or ``None`` after ``timeout`` seconds (or if it ended)."""
        fd = self.process.stdout.fileno()  # type: ignore[union-attr]
        while "\n" not in self._pending:
            if not select.select([fd], [], [], timeout)[0]:
                return None
            chunk = os.read(fd, 4096).decode()
            if not chunk:
                return None
            self._pending += chunk
        line, self._pending = self._pending.split("\n", 1)
        return line

    def run(self, command: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess[str]:
        stdout, stderr = self.folder / "stdout.txt", self.folder / "stderr.txt"
        stdout.write_text("")
        stderr.write_text(self.imports_output.read_text())  # what the imports printed, a fresh run prints too
        script, *args = command
        request = "\0".join([str(cwd), str(stdout), str(stderr), script, *args])
        assert "\n" not in request
        self.process.stdin.write(request + "\n")  # type: ignore[union-attr]
        self.process.stdin.flush()  # type: ignore[union-attr]
        pid = self._line(timeout=60)
        assert pid is not None, f"the example fork server did not answer:\n{self.imports_output.read_text()}"
        status = self._line(timeout=timeout)
        if status is None:
            os.kill(int(pid), signal.SIGKILL)
            self._line(timeout=60)
            raise subprocess.TimeoutExpired(command, timeout, stdout.read_text(), stderr.read_text())
        return subprocess.CompletedProcess(command, int(status), stdout.read_text(), stderr.read_text())

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.close()  # type: ignore[union-attr]
            self.process.wait(timeout=60)


_server: _ForkServer | None = None


def _fork_server() -> _ForkServer:
    global _server
    if _server is None or _server.process.poll() is not None:
        _server = _ForkServer()
    return _server


def _entries(folder: Path) -> set[str]:
    return {path.name for path in folder.iterdir()} if folder.is_dir() else set()


def run_quick(
    script: str, cwd: Path, *args: str, timeout: float, fresh: bool = False
) -> subprocess.CompletedProcess[str]:
    """Run ``examples/<script> --quick *args`` from ``cwd`` and check it wrote only under ``runs/<name>/``.

    The script runs in a child of the fork server (see the module docstring), or with ``fresh=True`` in a fresh
    interpreter (``sys.executable``). ``cwd`` must hold nothing but (inputs in) ``runs/``. Fails with both output
    streams on a non-zero exit, and with the new entries if the script left anything in ``cwd`` outside ``runs/``
    or in ``runs/`` outside ``runs/<script name without .py>/``, and with the lines of any Python warning it printed.
    """
    before = _entries(cwd)
    assert before <= {"runs"}, f"run {script} from an empty directory, not one holding {sorted(before)}"
    runs_before = _entries(cwd / "runs")
    command = [str(EXAMPLES / script), "--quick", *args]
    if fresh:
        command = [sys.executable, *command]
        result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False)
    else:
        result = _fork_server().run(command, cwd, timeout)
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
