"""dm_control itself as a reference: the venv that runs it, and a worker process that evaluates states in it.

dm-control 1.0.50 does not import on MuJoCo 4, so it runs in a venv of its own (dm-control 1.0.50 on MuJoCo 3.17.0;
``make test`` builds ``.venv-dmc``) and answers over a pipe: :class:`DmControlReference` starts one worker process
there (``_dm_control_worker.py``, which imports only numpy, mujoco and dm_control) and sends it N states at a time.
One control step from the same state agrees between MuJoCo 3.17.0 and 4.0.0 to ~1e-11 or better, so a comparison
state by state holds to that; free rollouts drift apart (:meth:`DmControlReference.rollout` measures it).

This module imports neither mujoco nor dm_control.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import tempfile
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from torchtasks.envs.control_suite._dm_control_worker import encode, read_frame, write_frame

#: the environment variable naming the reference python (else ``./.venv-dmc/bin/python`` from the current directory)
PYTHON_VARIABLE = "TORCHTASKS_DM_CONTROL_PYTHON"
#: the reference venv ``make test`` builds (``make reference-venv`` alone), relative to the repository root
DEFAULT_VENV = ".venv-dmc"
HOW_TO_BUILD = (
    f"`make test` builds {DEFAULT_VENV} in the repository (or `make reference-venv`: pip install mujoco==3.17.0 "
    f"dm-control==1.0.50, needs network), or set {PYTHON_VARIABLE} to a python that imports dm_control"
)
_WORKER = Path(__file__).with_name("_dm_control_worker.py")
_PROBE = "import dm_control.suite"
#: python path -> None when it imports dm_control's suite, else why not (checked once per path and process)
_CHECKED: dict[str, str | None] = {}


class DmControlUnavailableError(RuntimeError):
    """The reference python is absent or does not import dm_control (the message says how to build it)."""


def _candidate() -> tuple[str, str]:
    """(the reference python's absolute path, where it came from)."""
    configured = os.environ.get(PYTHON_VARIABLE)
    if configured:
        return os.path.abspath(os.path.expanduser(configured)), f"from {PYTHON_VARIABLE}"
    return os.path.abspath(os.path.join(DEFAULT_VENV, "bin", "python")), f"./{DEFAULT_VENV} in {os.getcwd()}"


def _worker_environment() -> dict[str, str]:
    """The environment of the reference python: no rendering, and none of this venv's import paths."""
    environment = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    environment["MUJOCO_GL"] = "disable"
    return environment


def _unavailable_reason(python: str) -> str | None:
    """None when ``python`` imports dm_control's suite, else why not (checked once per path, then cached)."""
    if python not in _CHECKED:
        reason = None
        if not os.path.isfile(python):
            reason = f"{python} does not exist"
        else:
            try:
                probe = subprocess.run(
                    [python, "-c", _PROBE], capture_output=True, text=True, env=_worker_environment(), timeout=300
                )
            except (OSError, subprocess.SubprocessError) as error:
                reason = f"{python} does not run ({error})"
            else:
                if probe.returncode != 0:
                    lines = probe.stderr.strip().splitlines() or [f"exit code {probe.returncode}"]
                    reason = f"{python} does not import dm_control.suite ({lines[-1]})"
        _CHECKED[python] = reason
    return _CHECKED[python]


def reference_python() -> str | None:
    """The python that runs dm_control for the reference, or None when there is none.

    It is ``$TORCHTASKS_DM_CONTROL_PYTHON`` when set, else ``./.venv-dmc/bin/python`` relative to the current
    directory (``make test`` builds that venv), as an absolute path, returned only if it imports dm_control's suite
    (checked once per path and process, in a subprocess).

    Returns:
        The path, or None.

    Example:
        >>> from torchtasks.envs.control_suite.reference import reference_python
        >>> python = reference_python()  # None without the reference venv
        >>> python is None or python.startswith("/")
        True
    """
    python, _ = _candidate()
    return python if _unavailable_reason(python) is None else None


def _stop(process: subprocess.Popen, stderr: IO[bytes]) -> None:
    """Ends the worker (closing its stdin ends its loop; killed if it does not exit) and drops its stderr file."""
    try:
        if process.poll() is None:
            for stream in (process.stdin, process.stdout):
                if stream is not None:
                    stream.close()
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    finally:
        stderr.close()


class DmControlReference:
    """dm_control (dm-control 1.0.50 on MuJoCo 3.17.0) in one worker process, evaluating N states per call.

    The worker loads each ``(domain, task)`` once (``suite.load`` with seed 0, then one ``reset``, which makes the
    task's fixed model edits such as reacher hard's target size) and keeps it. Every call sets each state on a
    freshly reset ``MjData`` (``ctrl`` and applied forces zero), writes the given per-state model fields, runs
    dm_control's own code and restores the model fields afterwards, so calls do not depend on each other. Model
    fields are written as they are, as dm_control's tasks write them (no ``mj_setConst``).
    All arrays are numpy float64, in and out (model fields in the dtype MuJoCo stores them).

    Errors: bad arguments and unknown domains, tasks or model fields are ValueError or TypeError with the worker's
    message; anything else the worker raised is a RuntimeError with its type, message and traceback; the worker
    keeps serving after either.

    Args:
        python: the reference python; by default :func:`reference_python`'s candidate. A python that does not
            import dm_control raises :class:`DmControlUnavailableError` saying how to build the venv.

    Example:
        >>> import numpy as np
        >>> from torchtasks.envs.control_suite.reference import DmControlReference, reference_python
        >>> if reference_python() is not None:  # `make test` builds the reference venv
        ...     with DmControlReference() as reference:
        ...         nq = int(reference.model_fields("cartpole", "swingup", ["nq"])["nq"])
        ...         out = reference.evaluate(
        ...             "cartpole", "swingup", qpos=np.zeros((1, nq)), qvel=np.zeros((1, nq)), act=np.zeros((1, 0)),
        ...             time=np.zeros(1), qacc_warmstart=np.zeros((1, nq)))
        ...     assert list(out["observation"]) == ["position", "velocity"]
        ...     assert out["observation"]["position"].tolist() == [[0.0, 1.0, 0.0]]  # cart, pole up: zz = 1, xz = 0
    """

    def __init__(self, python: str | None = None) -> None:
        if python is None:
            python, source = _candidate()
        else:
            python, source = os.path.abspath(python), "given"
        reason = _unavailable_reason(python)
        if reason is not None:
            raise DmControlUnavailableError(
                f"no dm_control reference: {reason} (the reference python {source}). {HOW_TO_BUILD}"
            )
        self.python = python
        self._stderr = tempfile.TemporaryFile()
        self._process = subprocess.Popen(
            [python, str(_WORKER)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            env=_worker_environment(),
        )
        self._finalizer = weakref.finalize(self, _stop, self._process, self._stderr)
        try:
            #: the worker's versions: python, numpy, mujoco, dm_control
            self.versions: dict[str, str] = self._reply("starting")
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> DmControlReference:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        """Whether the worker has ended (closed, or exited on its own)."""
        return not self._finalizer.alive or self._process.poll() is not None

    def close(self) -> None:
        """Ends the worker (a second call does nothing)."""
        if self._finalizer.alive and self._process.poll() is None:
            try:
                write_frame(self._process.stdin, {"op": "close"})
                read_frame(self._process.stdout)
            except (OSError, EOFError):
                pass
        self._finalizer()

    def _worker_gone(self, doing: str) -> RuntimeError:
        try:
            code = self._process.wait(timeout=10)  # its stdout ended: it is exiting
        except subprocess.TimeoutExpired:
            code = None
        self._stderr.seek(0)
        tail = self._stderr.read().decode(errors="replace").strip().splitlines()[-20:]
        output = "\n".join(tail) if tail else "(no output)"
        return RuntimeError(
            f"the dm_control worker ({self.python} {_WORKER.name}) ended while {doing} (exit code {code}); "
            f"its stderr:\n{output}"
        )

    def _reply(self, doing: str) -> Any:
        try:
            reply = read_frame(self._process.stdout)
        except (OSError, EOFError, ValueError) as error:
            raise self._worker_gone(doing) from error
        if reply["ok"]:
            return reply["result"]
        message = f"dm_control reference: {reply['message']}"
        if reply["type"] in ("ValueError", "TypeError"):
            raise (ValueError if reply["type"] == "ValueError" else TypeError)(message)
        raise RuntimeError(f"{message} ({reply['type']} in the dm_control worker)\n{reply['traceback']}")

    def _call(self, op: str, **args: Any) -> Any:
        if self.closed:
            raise RuntimeError(f"this DmControlReference is closed: cannot run {op} (start a new one)")
        request = {"op": op, "args": encode(args)}  # a TypeError names the argument, before anything is sent
        try:
            write_frame(self._process.stdin, request)
        except (OSError, ValueError) as error:
            raise self._worker_gone(f"receiving {op}") from error
        return self._reply(f"running {op}")

    def model_fields(self, domain: str, task: str, names: Sequence[str]) -> dict[str, np.ndarray]:
        """Fields of dm_control's compiled model for ``(domain, task)`` (after its load and first reset).

        Args:
            domain: a suite domain, e.g. ``"walker"``.
            task: one of its tasks, e.g. ``"walk"``.
            names: ``MjModel`` attributes, e.g. ``"nq"``, ``"body_mass"``, ``"opt.timestep"``.

        Returns:
            ``{name: array}`` (a copy; sizes and integer fields as integer arrays of shape ``()``).

        Example:
            >>> from torchtasks.envs.control_suite.reference import reference_python, shared_reference
            >>> if reference_python() is not None:  # `make test` builds the reference venv
            ...     fields = shared_reference().model_fields("walker", "walk", ["nq", "opt.timestep", "body_mass"])
            ...     assert int(fields["nq"]) == 9 and float(fields["opt.timestep"]) == 0.0025
            ...     assert fields["body_mass"].shape == (8,)
        """
        if isinstance(names, str) or not isinstance(names, Sequence):
            raise TypeError(f"names: expected a sequence of field names, got {type(names).__name__} {names!r}")
        return self._call("model_fields", domain=domain, task=task, names=list(names))

    def evaluate(
        self,
        domain: str,
        task: str,
        *,
        qpos: np.ndarray,
        qvel: np.ndarray,
        act: np.ndarray,
        time: np.ndarray,
        qacc_warmstart: np.ndarray,
        model_fields: dict[str, np.ndarray] | None = None,
        action: np.ndarray | None = None,
    ) -> dict[str, Any]:
        """dm_control's observation and reward at N states, or after one control step from each.

        Per state i: the model fields (``{name: [N, *field shape]}``, each written whole, e.g. ``"geom_pos"``
        ``[N, ngeom, 3]``) and the state are set; then, with ``action`` None, ``mj_forward`` with actuation disabled
        (``physics.after_reset``, as at the end of a reset) and the task's ``get_observation`` and ``get_reward``;
        with ``action`` ``[N, nu]``, ``mj_forward`` and then ``control.Environment.step``'s own path:
        ``task.before_step(action)``, ``physics.step(n_sub_steps)``, ``task.after_step``, ``get_reward``,
        ``get_observation``.

        Args:
            domain: a suite domain, e.g. ``"walker"``.
            task: one of its tasks.
            qpos: ``[N, nq]``.
            qvel: ``[N, nv]``.
            act: ``[N, na]``.
            time: ``[N]``.
            qacc_warmstart: ``[N, nv]`` (the solver's warm start).
            model_fields: per-state model fields, restored after the call.
            action: ``[N, nu]`` to step (written to ``ctrl`` unclipped, as dm_control does), or None.

        Returns:
            ``{"observation": {key: [N, *shape]} in dm_control's key order, "reward": [N]}``, and with an action
            also ``"qpos"``, ``"qvel"``, ``"act"``, ``"time"`` and ``"qacc_warmstart"`` after the step.

        Example:
            >>> import numpy as np
            >>> from torchtasks.envs.control_suite.reference import reference_python, shared_reference
            >>> if reference_python() is not None:  # `make test` builds the reference venv
            ...     state = dict(qpos=np.zeros((2, 2)), qvel=np.zeros((2, 2)), act=np.zeros((2, 0)), time=np.zeros(2),
            ...                  qacc_warmstart=np.zeros((2, 2)))
            ...     out = shared_reference().evaluate("cartpole", "swingup", **state, action=np.array([[1.0], [-1.0]]))
            ...     assert out["qvel"][0, 0] > 0 > out["qvel"][1, 0] and out["time"].tolist() == [0.01, 0.01]
        """
        return self._call(
            "evaluate",
            domain=domain,
            task=task,
            qpos=qpos,
            qvel=qvel,
            act=act,
            time=time,
            qacc_warmstart=qacc_warmstart,
            model_fields=model_fields,
            action=action,
        )

    def rollout(
        self,
        domain: str,
        task: str,
        *,
        qpos: np.ndarray,
        qvel: np.ndarray,
        act: np.ndarray,
        time: np.ndarray,
        actions: np.ndarray,
        model_fields: dict[str, np.ndarray] | None = None,
        qacc_warmstart: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """dm_control's physics stepped T control steps from N states with the given actions, never resynced.

        Each state is set as in :meth:`evaluate` (``qacc_warmstart`` zero unless given), ``mj_forward`` runs, then
        ``control.Environment.step``'s path T times. For measuring how trajectories of MuJoCo 3.17.0 and another
        version drift apart.

        Args:
            domain: a suite domain.
            task: one of its tasks.
            qpos: ``[N, nq]``.
            qvel: ``[N, nv]``.
            act: ``[N, na]``.
            time: ``[N]``.
            actions: ``[N, T, nu]``.
            model_fields: per-state model fields as in :meth:`evaluate`.
            qacc_warmstart: ``[N, nv]``, or None for zeros (as after a reset).

        Returns:
            ``{"qpos": [N, T, nq], "qvel": [N, T, nv], "act": [N, T, na], "reward": [N, T]}`` after each step.

        Example:
            >>> import numpy as np
            >>> from torchtasks.envs.control_suite.reference import reference_python, shared_reference
            >>> if reference_python() is not None:  # `make test` builds the reference venv
            ...     out = shared_reference().rollout(
            ...         "pendulum", "swingup", qpos=np.full((1, 1), 0.5), qvel=np.zeros((1, 1)), act=np.zeros((1, 0)),
            ...         time=np.zeros(1), actions=np.zeros((1, 3, 1)))
            ...     assert out["qpos"].shape == (1, 3, 1) and out["qvel"][0, 2, 0] > 0  # it falls away from upright (0)
        """
        return self._call(
            "rollout",
            domain=domain,
            task=task,
            qpos=qpos,
            qvel=qvel,
            act=act,
            time=time,
            actions=actions,
            model_fields=model_fields,
            qacc_warmstart=qacc_warmstart,
        )


_SHARED: list[DmControlReference] = []


def shared_reference() -> DmControlReference:
    """The process's one :class:`DmControlReference`, started on first use (again if it ended), closed at exit.

    Returns:
        The running reference; raises :class:`DmControlUnavailableError` without the reference venv.

    Example:
        >>> from torchtasks.envs.control_suite.reference import reference_python, shared_reference
        >>> if reference_python() is not None:
        ...     assert shared_reference() is shared_reference()
    """
    if not _SHARED or _SHARED[0].closed:
        _SHARED[:] = [DmControlReference()]
    return _SHARED[0]


@atexit.register
def _close_shared() -> None:
    for reference in _SHARED:
        reference.close()
