"""The dm_control side of ``torchtasks.envs.control_suite.reference``: a standalone script run by the reference venv.

``python _dm_control_worker.py`` (the reference venv's python: dm-control 1.0.50 on MuJoCo 3.17.0) serves requests
on stdin and answers on stdout, one frame each: an 8-byte big-endian length, then a pickle of plain Python values
(dicts, lists, str, int, float, bool, None and tuples) in which every numpy array is the tuple
``(ARRAY_TAG, dtype.str, shape, bytes)``, so that the two sides need not share a Python or numpy version. The first
frame is the worker's hello (its versions, or the error that stopped it from importing dm_control); every request
``{"op": name, "args": {...}}`` gets ``{"ok": True, "result": ...}`` or ``{"ok": False, "type": ..., "message":
..., "traceback": ...}``, and the worker keeps serving after an error. ``{"op": "close"}`` or the end of stdin ends
it.

This module imports only the standard library and numpy at import time (the client imports its frame functions);
mujoco and dm_control are imported when it runs as a script, never by torchtasks.
"""

from __future__ import annotations

import os
import pickle
import struct
import sys
import traceback
from typing import Any, BinaryIO

import numpy as np

ARRAY_TAG = "__ndarray__"
_LENGTH = struct.Struct(">Q")
_PICKLE_PROTOCOL = 4


def encode(value: Any, name: str = "") -> Any:
    """``value`` with every numpy array replaced by its tagged tuple (encoding twice changes nothing); a type that
    cannot cross is a TypeError naming it by ``name`` (a dict's entries by their keys when ``name`` is empty)."""
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject or value.dtype.fields is not None:
            raise TypeError(f"{name}: expected a numeric numpy array, got dtype {value.dtype}")
        return (ARRAY_TAG, value.dtype.str, tuple(value.shape), np.ascontiguousarray(value).tobytes())
    if isinstance(value, np.generic):
        return encode(np.asarray(value), name)
    if isinstance(value, dict):
        return {key: encode(item, f"{name}[{key!r}]" if name else key) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(encode(item, f"{name}[{index}]") for index, item in enumerate(value))
    if value is None or isinstance(value, (str, bool, int, float, bytes)):
        return value
    raise TypeError(f"{name}: expected numpy arrays, dicts, lists, str or numbers, got {type(value).__name__}")


def decode(value: Any) -> Any:
    """The inverse of :func:`encode` (arrays come back writable)."""
    if isinstance(value, tuple) and len(value) == 4 and value[0] == ARRAY_TAG:
        _, dtype, shape, data = value
        return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape).copy()
    if isinstance(value, dict):
        return {key: decode(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(decode(item) for item in value)
    return value


def write_frame(stream: BinaryIO, value: Any) -> None:
    """Writes one frame (``value`` encoded, pickled and length-prefixed) and flushes."""
    payload = pickle.dumps(encode(value), protocol=_PICKLE_PROTOCOL)
    stream.write(_LENGTH.pack(len(payload)))
    stream.write(payload)
    stream.flush()


def read_frame(stream: BinaryIO) -> Any:
    """Reads one frame; raises EOFError when the stream ends (before or inside a frame)."""
    header = _read_exactly(stream, _LENGTH.size)
    return decode(pickle.loads(_read_exactly(stream, _LENGTH.unpack(header)[0])))


def _read_exactly(stream: BinaryIO, size: int) -> bytes:
    chunks, remaining = [], size
    while remaining:
        chunk = stream.read(remaining)
        if not chunk:
            raise EOFError("the stream ended")
        chunks.append(chunk)
        remaining -= len(chunk)
    return b"".join(chunks)


# ---------------------------------------------------------------------------------------------------------------
# the dm_control side (runs in the reference venv only)

#: the MjData state arrays evaluate and rollout set: name -> the MjModel size of their trailing dim
_STATE = {"qpos": "nq", "qvel": "nv", "act": "na", "qacc_warmstart": "nv"}


class _Worker:
    """The requests: one dm_control environment per (domain, task), loaded once and reset once (seed 0)."""

    def __init__(self, suite: Any, mujoco: Any) -> None:
        self._suite = suite
        self._mujoco = mujoco
        self._envs: dict[tuple[str, str], Any] = {}

    def _env(self, domain: Any, task: Any) -> Any:
        if not isinstance(domain, str) or not isinstance(task, str):
            raise TypeError(f"domain and task: expected strings, got {type(domain).__name__}, {type(task).__name__}")
        key = (domain, task)
        if key not in self._envs:
            if domain not in self._suite._DOMAINS:
                raise ValueError(
                    f"domain: dm_control's suite has no domain {domain!r} ({sorted(self._suite._DOMAINS)})"
                )
            tasks = sorted(self._suite._DOMAINS[domain].SUITE)
            if task not in tasks:
                raise ValueError(f"task: dm_control's {domain!r} has no task {task!r} ({tasks})")
            env = self._suite.load(domain, task, task_kwargs={"random": 0})
            env.reset()  # the task's fixed model edits (e.g. reacher hard's target size) are made by its reset
            self._envs[key] = env
        return self._envs[key]

    # -- model fields ---------------------------------------------------------------------------------------------

    @staticmethod
    def _locate(model: Any, name: Any) -> tuple[Any, str, np.ndarray]:
        """(owner, attribute, current value as an array) of a model field named like "geom_pos" or "opt.timestep"."""
        if not isinstance(name, str):
            raise TypeError(f"model field names: expected strings, got {type(name).__name__}")
        owner, parts = model, name.split(".")
        for part in parts[:-1]:
            owner = None if part.startswith("_") else getattr(owner, part, None)
            if owner is None:
                raise ValueError(f"model field {name!r}: MjModel has no {part!r}")
        attribute = parts[-1]
        value = getattr(owner, attribute, None) if not attribute.startswith("_") else None
        if value is None:
            raise ValueError(f"model field {name!r}: MjModel has no field {attribute!r}")
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (np.ndarray, int, float, np.number)):
            raise ValueError(f"model field {name!r}: not a numeric field of MjModel (got {type(value).__name__})")
        array = np.array(value)  # a copy
        if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
            raise ValueError(f"model field {name!r}: not a numeric field of MjModel (dtype {array.dtype})")
        return owner, attribute, array

    @staticmethod
    def _write(owner: Any, attribute: str, value: np.ndarray) -> None:
        current = getattr(owner, attribute)
        if isinstance(current, np.ndarray):
            current[...] = value
        else:
            setattr(owner, attribute, value.item())

    def model_fields(self, domain: str, task: str, names: Any) -> dict[str, np.ndarray]:
        env = self._env(domain, task)
        if not isinstance(names, (list, tuple)):
            raise TypeError(f"names: expected a list of field names, got {type(names).__name__}")
        return {name: self._locate(env.physics.model, name)[2] for name in names}

    # -- states ---------------------------------------------------------------------------------------------------

    def _checked(
        self, env: Any, states: dict[str, Any], model_fields: Any, actions: Any, action_dims: int, optional: tuple = ()
    ) -> int:
        """The number of states N; every argument is checked against the model before anything is written (the
        states named in ``optional`` may be None)."""
        model = env.physics.model
        n = _leading(states["time"], 0)
        if n < 1:
            raise ValueError(
                f"time: expected a float64 array of shape (N,) with N >= 1, got {_describe(states['time'])}"
            )
        _check_array("time", states["time"], (n,), np.float64)
        for name, size in _STATE.items():
            if states[name] is not None or name not in optional:
                _check_array(name, states[name], (n, getattr(model, size)), np.float64)
        if action_dims == 2 and actions is not None:
            _check_array("action", actions, (n, model.nu), np.float64)
        if action_dims == 3:
            steps = _leading(actions, 1) if getattr(actions, "ndim", 0) == 3 else 0
            if steps < 1:
                raise ValueError(
                    f"actions: expected a float64 array of shape ({n}, T, {model.nu}) with T >= 1, "
                    f"got {_describe(actions)}"
                )
            _check_array("actions", actions, (n, steps, model.nu), np.float64)
        if model_fields is None:
            return n
        if not isinstance(model_fields, dict):
            raise TypeError(f"model_fields: expected a dict of field name -> array, got {type(model_fields).__name__}")
        for name, value in model_fields.items():
            owner, attribute, current = self._locate(model, name)
            _check_array(f"model_fields[{name!r}]", value, (n, *current.shape), current.dtype)
            try:  # the value it has: refused here (sizes, read-only arrays), not halfway through the states
                self._write(owner, attribute, current)
            except (AttributeError, ValueError, TypeError) as error:
                raise ValueError(f"model_fields[{name!r}]: MjModel's {name} is not writable ({error})") from None
        return n

    def _set_state(self, env: Any, states: dict[str, Any], fields: dict[str, tuple], i: int) -> None:
        """State i on a freshly reset MjData (ctrl, applied forces and warnings zero), model fields written first."""
        physics = env.physics
        self._mujoco.mj_resetData(physics.model.ptr, physics.data.ptr)
        for owner, attribute, values in fields.values():
            self._write(owner, attribute, values[i])
        physics.data.time = states["time"][i]
        for name in _STATE:
            if states[name] is not None:
                getattr(physics.data, name)[:] = states[name][i]

    def _with_fields(self, env: Any, model_fields: Any, body: Any) -> Any:
        """Runs ``body(fields)`` with the model fields located, then restores the fields as they were."""
        fields = {}
        for name, values in (model_fields or {}).items():
            owner, attribute, current = self._locate(env.physics.model, name)
            fields[name] = (owner, attribute, values, current)
        try:
            return body({name: field[:3] for name, field in fields.items()})
        finally:
            for owner, attribute, _, original in fields.values():
                self._write(owner, attribute, original)

    def evaluate(
        self,
        domain: str,
        task: str,
        qpos: Any,
        qvel: Any,
        act: Any,
        time: Any,
        qacc_warmstart: Any,
        model_fields: Any = None,
        action: Any = None,
    ) -> dict[str, Any]:
        env = self._env(domain, task)
        states = {"qpos": qpos, "qvel": qvel, "act": act, "time": time, "qacc_warmstart": qacc_warmstart}
        n = self._checked(env, states, model_fields, action, 2)
        physics, dm_task = env.physics, env.task

        def run(fields: dict[str, tuple]) -> dict[str, Any]:
            observations, rewards, after = [], [], {name: [] for name in ("qpos", "qvel", "act", "qacc_warmstart")}
            times = []
            for i in range(n):
                self._set_state(env, states, fields, i)
                if action is None:
                    physics.after_reset()  # mj_forward with actuation disabled, as at the end of a reset
                    observations.append(dm_task.get_observation(physics))
                    rewards.append(dm_task.get_reward(physics))
                    continue
                physics.forward()  # the step-1 results the legacy (Euler) step starts from
                # control.Environment.step, without its step count
                dm_task.before_step(action[i], physics)
                physics.step(env._n_sub_steps)
                dm_task.after_step(physics)
                rewards.append(dm_task.get_reward(physics))
                observations.append(dm_task.get_observation(physics))
                for name, rows in after.items():
                    rows.append(np.array(getattr(physics.data, name)))
                times.append(physics.data.time)
            result = {"observation": _stack_observations(observations), "reward": _float64(rewards, "reward")}
            if action is not None:
                result.update({name: np.stack(rows) for name, rows in after.items()})
                result["time"] = _float64(times, "time")
            return result

        return self._with_fields(env, model_fields, run)

    def rollout(
        self,
        domain: str,
        task: str,
        qpos: Any,
        qvel: Any,
        act: Any,
        time: Any,
        actions: Any,
        model_fields: Any = None,
        qacc_warmstart: Any = None,
    ) -> dict[str, Any]:
        env = self._env(domain, task)
        states = {"qpos": qpos, "qvel": qvel, "act": act, "time": time, "qacc_warmstart": qacc_warmstart}
        n = self._checked(env, states, model_fields, actions, 3, optional=("qacc_warmstart",))
        physics, dm_task = env.physics, env.task

        def run(fields: dict[str, tuple]) -> dict[str, Any]:
            steps = actions.shape[1]
            data = physics.data
            out = {
                "qpos": np.empty((n, steps, data.qpos.size)),
                "qvel": np.empty((n, steps, data.qvel.size)),
                "act": np.empty((n, steps, data.act.size)),
                "reward": np.empty((n, steps)),
            }
            for i in range(n):
                self._set_state(env, states, fields, i)
                physics.forward()
                for t in range(steps):
                    dm_task.before_step(actions[i, t], physics)
                    physics.step(env._n_sub_steps)
                    dm_task.after_step(physics)
                    out["reward"][i, t] = _float64([dm_task.get_reward(physics)], "reward")[0]
                    out["qpos"][i, t], out["qvel"][i, t], out["act"][i, t] = data.qpos, data.qvel, data.act
            return out

        return self._with_fields(env, model_fields, run)


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"{value.dtype} array of shape {tuple(value.shape)}"
    return type(value).__name__


def _leading(value: Any, axis: int) -> int:
    return value.shape[axis] if isinstance(value, np.ndarray) and value.ndim > axis else -1


def _check_array(name: str, value: Any, shape: tuple, dtype: Any) -> None:
    if not isinstance(value, np.ndarray) or value.dtype != dtype or tuple(value.shape) != tuple(shape):
        raise ValueError(f"{name}: expected a {np.dtype(dtype)} array of shape {tuple(shape)}, got {_describe(value)}")


def _float64(values: list, name: str) -> np.ndarray:
    array = np.asarray(values)
    if array.dtype != np.float64:
        raise RuntimeError(f"dm_control returned a {name} of dtype {array.dtype}, not float64")
    return array


def _stack_observations(observations: list) -> dict[str, np.ndarray]:
    keys = list(observations[0])
    out = {}
    for key in keys:
        out[key] = _float64([np.asarray(obs[key]) for obs in observations], f"observation {key!r}")
    return out


def main() -> None:
    # the protocol owns the original stdout; anything printed (Python or C) goes to stderr
    protocol_out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    sys.stdout = sys.stderr
    protocol_in = sys.stdin.buffer
    os.environ["MUJOCO_GL"] = "disable"  # no rendering: dm_control then imports without GLFW or EGL
    try:
        from importlib import metadata

        import mujoco
        from dm_control import suite

        worker = _Worker(suite, mujoco)
        hello = {
            "ok": True,
            "result": {
                "python": sys.version.split()[0],
                "numpy": np.__version__,
                "mujoco": mujoco.__version__,
                "dm_control": metadata.version("dm_control"),
            },
        }
    except Exception as error:
        write_frame(protocol_out, _error(error))
        return
    write_frame(protocol_out, hello)
    while True:
        try:
            request = read_frame(protocol_in)
        except EOFError:
            return
        if request.get("op") == "close":
            write_frame(protocol_out, {"ok": True, "result": None})
            return
        try:
            method = (
                getattr(worker, request["op"]) if request.get("op") in ("model_fields", "evaluate", "rollout") else None
            )
            if method is None:
                raise ValueError(f"unknown request {request.get('op')!r}")
            reply = {"ok": True, "result": method(**request["args"])}
        except Exception as error:
            reply = _error(error)
        write_frame(protocol_out, reply)


def _error(error: BaseException) -> dict[str, Any]:
    return {"ok": False, "type": type(error).__name__, "message": str(error), "traceback": traceback.format_exc()}


if __name__ == "__main__":
    main()
