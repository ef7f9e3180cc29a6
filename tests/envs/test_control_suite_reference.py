"""The dm_control reference worker against plain MuJoCo 4.0.0 (this venv), and its errors.

The worker runs dm-control 1.0.50 on MuJoCo 3.17.0 (``tests/reference_venv.py``). Here the same suite XMLs are
compiled in MuJoCo 4.0.0, states are drawn and stepped there (``mj_step(n_sub_steps)`` then ``mj_step1``, which
is dm_control's step under one MuJoCo version), and the worker's next state, observation entries and reward must
equal that state and the formulas of dm_control's tasks computed from the 4.0.0 ``MjData`` (one step agrees
between the two versions to ~1e-11). The reward formulas use dm_control's own ``rewards.tolerance`` (numpy only,
installed in this venv without the rest of dm_control).
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")
dm_rewards = pytest.importorskip("dm_control.utils.rewards")

from model_files import dm_control_suite_xml  # noqa: E402
from torchtasks.envs.control_suite import reference  # noqa: E402

#: the next state and the observation after one control step, MuJoCo 3.17.0 (worker) against 4.0.0 (here)
STEP_ATOL = 1e-9
#: the observation of the same state after mj_forward only (no integration between the two versions)
FORWARD_ATOL = 1e-12

#: on the tests that ask the worker: one worker per test process, so they run in one group
GROUP = "dm_control_reference"


def _model(xml: str):
    return mujoco.MjModel.from_xml_path(str(dm_control_suite_xml(xml)))


def _tolerance(x, bounds=(0.0, 0.0), margin=0.0, sigmoid="gaussian", value_at_margin=0.1):
    return dm_rewards.tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value_at_margin)


# ------------------------------------------------------------------------------------------------ the task formulas


def _walker_observation(m, d) -> dict[str, np.ndarray]:
    return {
        "orientations": d.xmat[1:, [0, 2]].ravel(),  # xx, xz of every body but the world
        "height": np.array(d.xpos[m.body("torso").id, 2]),
        "velocity": d.qvel.copy(),
    }


def _walker_walk_reward(m, d) -> float:
    height = d.xpos[m.body("torso").id, 2]
    standing = _tolerance(height, bounds=(1.2, float("inf")), margin=0.6)
    upright = (1 + d.xmat[m.body("torso").id, 8]) / 2
    stand = (3 * standing + upright) / 4
    speed = d.sensordata[m.sensor("torso_subtreelinvel").adr[0]]
    move = _tolerance(speed, bounds=(1.0, float("inf")), margin=0.5, value_at_margin=0.5, sigmoid="linear")
    return stand * (5 * move + 1) / 6


def _cartpole_observation(m, d) -> dict[str, np.ndarray]:
    pole = m.body("pole_1").id
    return {"position": np.array([d.qpos[0], d.xmat[pole, 8], d.xmat[pole, 2]]), "velocity": d.qvel.copy()}


def _cartpole_swingup_reward(m, d) -> float:
    upright = (d.xmat[m.body("pole_1").id, 8] + 1) / 2
    centered = (1 + _tolerance(d.qpos[0], margin=2)) / 2
    small_control = (4 + _tolerance(d.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic")[0]) / 5
    small_velocity = (1 + np.min(_tolerance(d.qvel[1:], margin=5))) / 2
    return upright * small_control * small_velocity * centered


def _walker_draw(m, d, rng: np.random.Generator) -> None:
    """dm_control's walker reset: rooty U(-pi, pi), the limited joints U(range); the slides at 0."""
    d.qpos[2] = rng.uniform(-np.pi, np.pi)
    limited = m.jnt_limited.astype(bool)
    d.qpos[limited] = rng.uniform(m.jnt_range[limited, 0], m.jnt_range[limited, 1])


def _cartpole_draw(m, d, rng: np.random.Generator) -> None:
    d.qpos[:] = rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, np.pi)
    d.qvel[:] = rng.normal(size=2)


@dataclass(frozen=True)
class Case:
    """A task checked against MuJoCo 4.0.0: its XML, dm_control's n_sub_steps, a start draw and the formulas."""

    domain: str
    task: str
    xml: str
    n_sub_steps: int
    draw: Callable
    observation: Callable
    reward: Callable
    contacts: bool


CASES = {
    "walker-walk (Euler, contacts)": Case(
        "walker", "walk", "walker.xml", 10, _walker_draw, _walker_observation, _walker_walk_reward, True
    ),
    "cartpole-swingup (RK4)": Case(
        "cartpole",
        "swingup",
        "cartpole.xml",
        1,
        _cartpole_draw,
        _cartpole_observation,
        _cartpole_swingup_reward,
        False,
    ),
}

STATE_KEYS = ("qpos", "qvel", "act", "time", "qacc_warmstart")


def _set(m, d, state: dict[str, np.ndarray], i: int) -> None:
    mujoco.mj_resetData(m, d)
    d.time = state["time"][i]
    for key in ("qpos", "qvel", "act", "qacc_warmstart"):
        getattr(d, key)[:] = state[key][i]


def _mujoco4_step(m, d, action: np.ndarray, n_sub_steps: int) -> None:
    d.ctrl[:] = action
    mujoco.mj_step(m, d, n_sub_steps)
    mujoco.mj_step1(m, d)


def _draw_states(case: Case, m, envs: int = 4, steps: tuple[int, ...] = (3, 12, 25)) -> dict[str, np.ndarray]:
    """States from random rollouts in MuJoCo 4.0.0 (contacts, warm starts, nonzero time): envs x len(steps)."""
    rng = np.random.default_rng(7)
    d = mujoco.MjData(m)
    rows: dict[str, list] = {key: [] for key in STATE_KEYS}
    for _ in range(envs):
        mujoco.mj_resetData(m, d)
        case.draw(m, d, rng)
        mujoco.mj_forward(m, d)
        for step in range(1, max(steps) + 1):
            _mujoco4_step(m, d, rng.uniform(-1, 1, m.nu), case.n_sub_steps)
            if step in steps:
                for key in STATE_KEYS:
                    rows[key].append(np.array(getattr(d, key), dtype=np.float64))
    return {key: np.stack(values) for key, values in rows.items()}


def _assert_observation(got: dict[str, np.ndarray], expected: list[dict[str, np.ndarray]], atol: float) -> None:
    assert list(got) == list(expected[0])  # dm_control's key order
    for key in got:
        want = np.stack([row[key] for row in expected])
        assert got[key].dtype == np.float64 and got[key].shape == want.shape, key
        np.testing.assert_allclose(got[key], want, rtol=0, atol=atol, err_msg=key)


# ------------------------------------------------------------------------------------------------ the worker's answers


@pytest.mark.dm_control_reference
@pytest.mark.xdist_group(GROUP)
@pytest.mark.parametrize("name", list(CASES))
def test_one_control_step_and_reset_readings_equal_mujoco4_and_the_task_formulas(dm_control_reference, name: str):
    case = CASES[name]
    m = _model(case.xml)
    fields = dm_control_reference.model_fields(case.domain, case.task, ["nq", "nv", "nu", "na", "opt.timestep"])
    assert [int(fields[key]) for key in ("nq", "nv", "nu", "na")] == [m.nq, m.nv, m.nu, m.na]
    assert float(fields["opt.timestep"]) == m.opt.timestep
    state = _draw_states(case, m)
    n = len(state["time"])
    actions = np.random.default_rng(3).uniform(-1.3, 1.3, (n, m.nu))  # beyond ctrlrange: dm_control never clips

    stepped = dm_control_reference.evaluate(case.domain, case.task, **state, action=actions)
    at_reset = dm_control_reference.evaluate(case.domain, case.task, **state)

    d = mujoco.MjData(m)
    expected = {key: [] for key in (*STATE_KEYS, "observation", "reward")}
    for i in range(n):
        _set(m, d, state, i)
        _mujoco4_step(m, d, actions[i], case.n_sub_steps)
        for key in STATE_KEYS:
            expected[key].append(np.array(getattr(d, key)))
        expected["observation"].append(case.observation(m, d))
        expected["reward"].append(case.reward(m, d))
    for key in STATE_KEYS:
        np.testing.assert_allclose(stepped[key], np.stack(expected[key]), rtol=0, atol=STEP_ATOL, err_msg=key)
    _assert_observation(stepped["observation"], expected["observation"], STEP_ATOL)
    np.testing.assert_allclose(stepped["reward"], expected["reward"], rtol=0, atol=STEP_ATOL)
    assert len(np.unique(np.round(stepped["reward"], 6))) > n // 2  # the states are not all alike

    forwarded = {"observation": [], "reward": []}
    contacts = []
    for i in range(n):  # dm_control's reset forward: ctrl 0 (actuation disabled), the state as given
        _set(m, d, state, i)
        mujoco.mj_forward(m, d)
        contacts.append(d.ncon)
        forwarded["observation"].append(case.observation(m, d))
        forwarded["reward"].append(case.reward(m, d))
    _assert_observation(at_reset["observation"], forwarded["observation"], FORWARD_ATOL)
    np.testing.assert_allclose(at_reset["reward"], forwarded["reward"], rtol=0, atol=FORWARD_ATOL)
    assert set(at_reset) == {"observation", "reward"}
    assert (max(contacts) > 0) == case.contacts  # walker's states touch the floor (cartpole has no contacts)


def _reacher_states(m, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    qpos = np.stack([rng.uniform(-np.pi, np.pi, n), rng.uniform(*m.jnt_range[1], n)], axis=1)
    return {
        "qpos": qpos,
        "qvel": rng.normal(size=(n, m.nv)),
        "act": np.zeros((n, 0)),
        "time": np.zeros(n),
        "qacc_warmstart": np.zeros((n, m.nv)),
    }


@pytest.mark.dm_control_reference
@pytest.mark.xdist_group(GROUP)
def test_model_fields_are_written_per_state_and_restored_after_the_call(dm_control_reference):
    m = _model("reacher.xml")
    target, finger = m.geom("target").id, m.geom("finger").id
    names = ["geom_pos", "geom_size", "body_mass", "ngeom"]
    easy = dm_control_reference.model_fields("reacher", "easy", names)
    hard = dm_control_reference.model_fields("reacher", "hard", names)
    # the model after the task's first reset: its fixed edit (the target's radius) made, the rest as compiled
    assert (easy["geom_size"][target, 0], hard["geom_size"][target, 0]) == (0.05, 0.015)
    np.testing.assert_array_equal(easy["body_mass"], m.body_mass)
    assert easy["geom_pos"].shape == (m.ngeom, 3) and int(easy["ngeom"]) == m.ngeom

    n = 6
    rng = np.random.default_rng(11)
    state = _reacher_states(m, n, rng)
    angle, radius = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.05, 0.2, n)
    radius[:2] = 0.0  # targets on the base, within reach of no finger: reward 0 there ...
    geom_pos = np.repeat(easy["geom_pos"][None], n, axis=0)
    geom_pos[:, target, 0], geom_pos[:, target, 1] = radius * np.sin(angle), radius * np.cos(angle)
    d = mujoco.MjData(m)
    finger_xy = []
    for i in range(n):
        _set(m, d, state, i)
        mujoco.mj_forward(m, d)
        finger_xy.append(d.geom_xpos[finger, :2].copy())
    geom_pos[2, target, :2] = finger_xy[2]  # ... and one target exactly under the finger: reward 1
    finger_xy = np.stack(finger_xy)

    out = dm_control_reference.evaluate("reacher", "easy", **state, model_fields={"geom_pos": geom_pos})
    assert list(out["observation"]) == ["position", "to_target", "velocity"]
    to_target = geom_pos[:, target, :2] - finger_xy
    np.testing.assert_allclose(out["observation"]["to_target"], to_target, rtol=0, atol=FORWARD_ATOL)
    within = np.linalg.norm(to_target, axis=1) <= 0.05 + 0.01  # the target's radius (easy) + the finger's
    np.testing.assert_array_equal(out["reward"], within.astype(np.float64))
    assert out["reward"][2] == 1.0 and not out["reward"][:2].any()

    # restored: without model fields, the target is where the first reset put it
    again = dm_control_reference.evaluate("reacher", "easy", **state)
    assert dm_control_reference.model_fields("reacher", "easy", ["geom_pos"])["geom_pos"].tolist() == (
        easy["geom_pos"].tolist()
    )
    np.testing.assert_allclose(
        again["observation"]["to_target"], easy["geom_pos"][target, :2] - finger_xy, rtol=0, atol=FORWARD_ATOL
    )

    # a scalar option and an int field cross too (e.g. a longer timestep in one state, one step)
    timestep = np.array([0.02, 0.04, 0.02, 0.02, 0.02, 0.02])
    stepped = dm_control_reference.evaluate(
        "reacher", "easy", **state, model_fields={"opt.timestep": timestep}, action=np.zeros((n, m.nu))
    )
    np.testing.assert_array_equal(stepped["time"], timestep)


@pytest.mark.dm_control_reference
@pytest.mark.xdist_group(GROUP)
def test_rollout_follows_dm_controls_step_and_drifts_little_from_mujoco4(dm_control_reference):
    case = CASES["walker-walk (Euler, contacts)"]
    m = _model(case.xml)
    state = {key: value[:3] for key, value in _draw_states(case, m, envs=1).items()}
    steps = 20
    actions = np.random.default_rng(5).uniform(-1, 1, (3, steps, m.nu))
    out = dm_control_reference.rollout(case.domain, case.task, **state, actions=actions)
    assert {key: value.shape for key, value in out.items()} == {
        "qpos": (3, steps, m.nq),
        "qvel": (3, steps, m.nv),
        "act": (3, steps, 0),
        "reward": (3, steps),
    }
    # the first step is evaluate's step, bit for bit (the same process and MuJoCo)
    first = dm_control_reference.evaluate(case.domain, case.task, **state, action=actions[:, 0])
    for key in ("qpos", "qvel", "reward"):
        np.testing.assert_array_equal(out[key][:, 0], first[key])
    # free-running 4.0.0 trajectories from the same states: the drift grows (4e-14 in qpos after 20 steps, 3e-8 after
    # 200 on this machine), still within the one-step tolerance here
    d = mujoco.MjData(m)
    for i in range(3):
        _set(m, d, state, i)
        for t in range(steps):
            _mujoco4_step(m, d, actions[i, t], case.n_sub_steps)
            np.testing.assert_allclose(out["qpos"][i, t], d.qpos, rtol=0, atol=STEP_ATOL)
            np.testing.assert_allclose(out["qvel"][i, t], d.qvel, rtol=0, atol=STEP_ATOL)
            np.testing.assert_allclose(out["reward"][i, t], case.reward(m, d), rtol=0, atol=STEP_ATOL)


@pytest.mark.dm_control_reference
@pytest.mark.xdist_group(GROUP)
def test_bad_requests_are_clear_errors_that_change_nothing(dm_control_reference):
    m = _model("reacher.xml")
    n = 3
    state = _reacher_states(m, n, np.random.default_rng(2))
    baseline = dm_control_reference.evaluate("reacher", "easy", **state, action=np.ones((n, m.nu)))
    geom_pos = np.repeat(dm_control_reference.model_fields("reacher", "easy", ["geom_pos"])["geom_pos"][None], n, 0)
    geom_pos[:, m.geom("target").id, :2] = 0.1  # a valid field: refused with the others, so never written
    nan = state["qpos"].copy()
    nan[1] = np.nan  # the second state: the fields of the first were written when dm_control raises
    expected = "expected a float64 array of shape"
    cases = [  # (the arguments changed, the error, the start of its message after "dm_control reference: ")
        ({"domain": "reachr"}, ValueError, "domain: dm_control's suite has no domain 'reachr' (['acrobot', "),
        ({"task": "medium"}, ValueError, "task: dm_control's 'reacher' has no task 'medium' (['easy', 'hard'])"),
        ({"domain": 3}, TypeError, "domain and task: expected strings, got int, str"),
        ({"qpos": state["qpos"][:, :1]}, ValueError, f"qpos: {expected} (3, 2), got float64 array of shape (3, 1)"),
        ({"qvel": state["qvel"].astype(np.float32)}, ValueError, f"qvel: {expected} (3, 2), got float32 array of"),
        ({"act": np.zeros((n, 1))}, ValueError, f"act: {expected} (3, 0), got float64 array of shape (3, 1)"),
        ({"time": np.zeros(4)}, ValueError, f"qpos: {expected} (4, 2), got float64 array of shape (3, 2)"),
        ({"time": np.zeros(0)}, ValueError, "time: expected a float64 array of shape (N,) with N >= 1, got float64"),
        ({"qacc_warmstart": None}, ValueError, f"qacc_warmstart: {expected} (3, 2), got NoneType"),
        ({"qpos": state["qpos"].tolist()}, ValueError, f"qpos: {expected} (3, 2), got list"),
        ({"action": np.ones((n, 3))}, ValueError, f"action: {expected} (3, 2), got float64 array of shape (3, 3)"),
        ({"action": np.ones(m.nu)}, ValueError, f"action: {expected} (3, 2), got float64 array of shape (2,)"),
        (
            {"model_fields": {"geom_pos": geom_pos, "geom_size": np.zeros((n, 1))}},
            ValueError,
            f"model_fields['geom_size']: {expected} (3, 10, 3), got float64 array of shape (3, 1)",
        ),
        (
            {"model_fields": {"geom_pos": geom_pos, "geom_poss": geom_pos}},
            ValueError,
            "model field 'geom_poss': MjModel has no field 'geom_poss'",
        ),
        (
            {"model_fields": {"geom_pos": geom_pos.astype(np.float32)}},
            ValueError,
            f"model_fields['geom_pos']: {expected}",
        ),
        (
            {"model_fields": {"geom_type": np.zeros((n, m.ngeom))}},
            ValueError,
            "model_fields['geom_type']: expected a int32 array of shape (3, 10), got float64",
        ),
        ({"model_fields": {"nq": np.full(n, 2)}}, ValueError, "model_fields['nq']: MjModel's nq is not writable"),
        ({"model_fields": [geom_pos]}, TypeError, "model_fields: expected a dict of field name -> array, got list"),
    ]
    for overrides, error, message in cases:
        request = {"domain": "reacher", "task": "easy", **state, "action": np.ones((n, m.nu)), **overrides}
        with pytest.raises(error, match=re.escape(f"dm_control reference: {message}")):
            dm_control_reference.evaluate(request.pop("domain"), request.pop("task"), **request)
    # not sent at all: a value that cannot cross the pipe
    with pytest.raises(TypeError, match=r"^qpos: expected numpy arrays, dicts, lists, str or numbers, got object$"):
        dm_control_reference.evaluate("reacher", "easy", **{**state, "qpos": object()})
    # a failure inside dm_control is a RuntimeError naming it, after the fields were written: restored all the same
    with pytest.raises(RuntimeError, match=r"Physics state is invalid.*\(PhysicsError in the dm_control worker\)"):
        dm_control_reference.evaluate(
            "reacher", "easy", **{**state, "qpos": nan}, model_fields={"geom_pos": geom_pos}, action=np.ones((n, m.nu))
        )
    rollout_state = {key: value for key, value in state.items() if key != "qacc_warmstart"}  # optional there
    for actions in (np.ones((n, 0, m.nu)), np.ones((n, m.nu)), None):
        with pytest.raises(ValueError, match=re.escape(f"actions: {expected} (3, T, 2) with T >= 1, got ")):
            dm_control_reference.rollout("reacher", "easy", **rollout_state, actions=actions)
    with pytest.raises(ValueError, match=re.escape(f"actions: {expected} (3, 1, 2), got float32 array")):
        dm_control_reference.rollout("reacher", "easy", **rollout_state, actions=np.ones((n, 1, m.nu), np.float32))
    with pytest.raises(ValueError, match="model field 'body_masses': MjModel has no field 'body_masses'"):
        dm_control_reference.model_fields("reacher", "easy", ["body_mass", "body_masses"])
    with pytest.raises(ValueError, match=re.escape("model field 'opt.nothing': MjModel has no field 'nothing'")):
        dm_control_reference.model_fields("reacher", "easy", ["opt.nothing"])
    with pytest.raises(TypeError, match="names: expected a sequence of field names, got str 'geom_pos'"):
        dm_control_reference.model_fields("reacher", "easy", "geom_pos")

    again = dm_control_reference.evaluate("reacher", "easy", **state, action=np.ones((n, m.nu)))
    for key in ("qpos", "qvel", "reward"):
        np.testing.assert_array_equal(again[key], baseline[key])
    np.testing.assert_array_equal(again["observation"]["to_target"], baseline["observation"]["to_target"])

    # a second worker of the same python, ended by its context manager
    with reference.DmControlReference(dm_control_reference.python) as other:
        assert other.versions == dm_control_reference.versions
        assert other.versions["dm_control"] == "1.0.50" and other.versions["mujoco"] == "3.17.0"
    assert other.closed and other._process.returncode == 0
    with pytest.raises(RuntimeError, match="this DmControlReference is closed: cannot run model_fields"):
        other.model_fields("reacher", "easy", ["nq"])
    other.close()  # again: nothing


def _fake_python(folder: Path, script: str) -> str:
    path = folder / "python"
    path.write_text(f"#!/bin/sh\n{script}\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


def test_without_a_reference_python_the_error_says_how_to_get_one(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv(reference.PYTHON_VARIABLE, raising=False)
    monkeypatch.chdir(tmp_path)
    assert reference.reference_python() is None
    with pytest.raises(reference.DmControlUnavailableError) as info:
        reference.DmControlReference()
    message = str(info.value)
    expected = (os.path.join(tmp_path, ".venv-dmc", "bin", "python"), "does not exist", f"./.venv-dmc in {tmp_path}")
    assert all(part in message for part in (*expected, "`make test` builds .venv-dmc", reference.PYTHON_VARIABLE))

    # a python that does not import dm_control, named by the variable
    fake = _fake_python(tmp_path, "echo \"ModuleNotFoundError: No module named 'dm_control'\" >&2; exit 1")
    monkeypatch.setenv(reference.PYTHON_VARIABLE, fake)
    assert reference.reference_python() is None
    with pytest.raises(reference.DmControlUnavailableError, match=r"No module named 'dm_control'.*from TORCHTASKS_DM"):
        reference.DmControlReference()
    assert isinstance(info.value, RuntimeError)


def test_a_worker_that_dies_is_a_runtime_error_with_its_stderr(tmp_path: Path) -> None:
    # passes the import check (python -c ...), then the worker itself fails
    fake = _fake_python(tmp_path, 'if [ "$1" = "-c" ]; then exit 0; fi\necho "worker: cannot start" >&2; exit 3')
    with pytest.raises(RuntimeError, match=r"ended while starting \(exit code 3\); its stderr:\nworker: cannot start"):
        reference.DmControlReference(fake)
