"""Reset steps of BatchedMujocoEnv (``Resets(steps=...)``, torchtasks.envs.reset_steps), against raw MuJoCo and numpy.

Every expectation is computed here from the model's own numbers and the per-env generators by their definition
(``generators`` of test_batched_models: PCG64 of ``SeedSequence(seed).spawn(num_envs)``), drawing in the order the
steps are declared: joints drawn in their ranges (``UniformJoints``, ``NormalJoints``, ``CopyJoints``), orientations
(``RandomOrientation``), domain fields drawn per env (``DrawDomain`` with ``Box``, ``Ring``, ``AxisAngle``,
``Choice``) and compared with a per-env ``MjModel`` copy set by hand (``reference_model`` of
test_batched_mujoco_domain) and ``mj_forward``, rejection until no contact (``UntilContactFree``: ``ncon`` of an
independent ``MjData`` per env), the floating base raised until free (``RaiseUntilContactFree``) and settling steps
(``Settle``: ``mj_step`` of an independent ``MjData`` from the drawn state). Then what a run relies on: an env's
draws do not depend on which others reset, ``set_seed`` reproduces, checkpoints, copies and pickles continue bit
for bit, resets to given states skip the steps that write the state, and bad declarations are refused naming the
argument.
"""

from __future__ import annotations

import copy
import math
import pickle
import re
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from test_batched_models import generators  # noqa: E402
from test_batched_mujoco_domain import reference_model  # noqa: E402

from model_files import dm_control_suite_xml  # noqa: E402
from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs import readings as R  # noqa: E402
from torchtasks.envs.models import model_path  # noqa: E402
from torchtasks.envs.mujoco_declaration import Resets  # noqa: E402
from torchtasks.envs.reset_steps import (  # noqa: E402
    AxisAngle,
    Box,
    Choice,
    CopyJoints,
    DrawDomain,
    NormalJoints,
    RaiseUntilContactFree,
    RandomOrientation,
    ResetStep,
    Ring,
    Settle,
    UniformJoints,
    UntilContactFree,
)

pytestmark = [
    pytest.mark.mujoco,
    # MuJoCo 4 about dm_control's cheetah.xml (a file no one here wrote), when the env or the test compiles it
    pytest.mark.filterwarnings("ignore:compiler attribute 'settotalmass' is deprecated:UserWarning"),
]

#: every joint type, limited and not; the free body and the ball joint's body touch nothing (contype 0)
JOINTS_XML = """
<mujoco>
  <compiler angle="radian"/>
  <default><geom contype="0" conaffinity="0" size="0.05"/></default>
  <worldbody>
    <body name="arm" pos="0 0 1">
      <joint name="hinge_limited" type="hinge" axis="0 1 0" range="-1 0.5"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0"/>
      <body name="forearm" pos="0.3 0 0">
        <joint name="hinge_unlimited" type="hinge" axis="0 1 0" ref="0.2"/>
        <joint name="slide_limited" type="slide" axis="1 0 0" range="0.1 0.4"/>
        <joint name="slide_unlimited" type="slide" axis="0 0 1" ref="0.25"/>
        <geom type="sphere"/>
        <body name="hand" pos="0.1 0 0">
          <joint name="wrist" type="ball"/>
          <geom type="box" size="0.05 0.02 0.01"/>
        </body>
      </body>
    </body>
    <body name="box" pos="0.3 -0.2 1.5" quat="0.9 0.1 0.2 0.3">
      <freejoint name="root"/>
      <geom type="box" size="0.1 0.2 0.3"/>
    </body>
  </worldbody>
  <actuator><motor joint="hinge_limited"/></actuator>
</mujoco>
"""

#: a ball on a plane (x, z slides in [-1, 1]) and a wall that takes most of it: most uniform draws collide
WALL_XML = """
<mujoco>
  <worldbody>
    <geom name="wall" type="box" pos="0.1 0 0" size="0.8 0.5 0.8"/>
    <geom name="post" type="box" pos="2 0 0" size="0.1 0.1 0.1"/>
    <body name="ball">
      <joint name="x" type="slide" axis="1 0 0" range="-1 1"/>
      <joint name="z" type="slide" axis="0 0 1" range="-1 1"/>
      <geom name="ball" type="sphere" size="0.1"/>
    </body>
  </worldbody>
  <actuator><motor joint="x"/></actuator>
</mujoco>
"""


def _env(model: Any, n: int, steps: list[ResetStep], seed: int = 0, **kwargs: Any) -> BatchedMujocoEnv:
    kwargs.setdefault("observation", {"qpos": R.joint_pos(), "qvel": R.joint_vel()})
    return BatchedMujocoEnv(model, n, resets=Resets(steps=steps), seed=seed, **kwargs)


def _mask(n: int, *rows: int) -> torch.Tensor:
    mask = torch.zeros(n, dtype=torch.bool)
    mask[list(rows)] = True
    return mask


def _qpos(env: BatchedMujocoEnv) -> np.ndarray:
    return env.batch.bind("qpos").copy()


def _adr(model: mujoco.MjModel, joint: str) -> int:
    return int(model.joint(joint).qposadr[0])


def _ncon(model: mujoco.MjModel, qpos: np.ndarray) -> int:
    """The contacts of ``qpos`` in an MjData of its own (mj_forward)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    return int(data.ncon)


def _assert_uniform(values: np.ndarray, low: float, high: float, what: str) -> None:
    """Draws of ``U[low, high)``: in range, mean and spread as the distribution's (5 standard errors)."""
    n = values.size
    assert low <= values.min() and values.max() < high, what
    assert abs(values.mean() - (low + high) / 2) < 5 * (high - low) / math.sqrt(12 * n), what
    assert abs(values.std() / ((high - low) / math.sqrt(12)) - 1) < 0.1, what


# ------------------------------------------------------------------------------ joints and orientations
N_DRAWS = 600


def test_uniform_joints_of_none_draws_limited_joints_and_unlimited_hinges_and_nothing_else() -> None:
    env = _env(JOINTS_XML, N_DRAWS, [UniformJoints()], seed=3, stage="step")
    env.reset()
    model, qpos = env.model, _qpos(env)
    # in model order: every limited hinge or slide in its range, every unlimited hinge in [-pi, pi)
    drawn = ["hinge_limited", "hinge_unlimited", "slide_limited"]
    ranges = {
        "hinge_limited": tuple(model.joint("hinge_limited").range),
        "hinge_unlimited": (-math.pi, math.pi),
        "slide_limited": tuple(model.joint("slide_limited").range),
    }
    assert ranges["hinge_limited"] == (-1.0, 0.5) and ranges["slide_limited"] == (0.1, 0.4)
    low, high = np.array([ranges[j] for j in drawn]).T
    columns = [_adr(model, j) for j in drawn]
    for i, rng in enumerate(generators(3, N_DRAWS)):
        np.testing.assert_array_equal(qpos[i, columns], rng.uniform(low, high), err_msg=f"env {i}")
    for joint in drawn:
        _assert_uniform(qpos[:, _adr(model, joint)], *ranges[joint], what=joint)
    # the unlimited slide, the ball and the free joint keep qpos0; no velocity is drawn
    untouched = np.setdiff1d(np.arange(model.nq), columns)
    assert untouched.size == model.nq - 3
    np.testing.assert_array_equal(qpos[:, untouched], np.tile(model.qpos0[untouched], (N_DRAWS, 1)))
    assert model.qpos0[_adr(model, "slide_unlimited")] == 0.25
    assert (env.batch.bind("qvel") == 0).all()
    env.close()


def test_named_joints_orientations_and_copies_draw_in_the_declared_order() -> None:
    """One declaration of every joint step; each env's state is its generator's draws, step by step."""
    steps = [
        UniformJoints(["slide_limited", "hinge_unlimited"]),  # the order given, not the model's
        UniformJoints({"slide_unlimited": (-0.3, 0.3), "hinge_limited": (0.1, 0.2)}),
        NormalJoints({"hinge_unlimited": (0.5, 0.2)}),
        RandomOrientation("root"),  # uniform on rotations: a normalised 4D Gaussian
        RandomOrientation("wrist", "positive"),  # a normalised U[0, 1)^4
        CopyJoints({"slide_limited": "hinge_limited"}),
    ]
    env = _env(JOINTS_XML, N_DRAWS, steps, seed=5, stage="step")
    env.reset()
    model, qpos = env.model, _qpos(env)
    a = {name: _adr(model, name) for name in ("hinge_limited", "hinge_unlimited", "slide_limited", "slide_unlimited")}
    root, wrist = _adr(model, "root"), _adr(model, "wrist")
    for i, rng in enumerate(generators(5, N_DRAWS)):
        expected = model.qpos0.copy()
        expected[[a["slide_limited"], a["hinge_unlimited"]]] = rng.uniform([0.1, -math.pi], [0.4, math.pi])
        expected[[a["slide_unlimited"], a["hinge_limited"]]] = rng.uniform([-0.3, 0.1], [0.3, 0.2])
        expected[a["hinge_unlimited"]] = 0.5 + 0.2 * rng.standard_normal(1)[0]
        q = rng.standard_normal(4)
        expected[root + 3 : root + 7] = q / np.linalg.norm(q)
        q = rng.random(4)
        expected[wrist : wrist + 4] = q / np.linalg.norm(q)
        expected[a["slide_limited"]] = expected[a["hinge_limited"]]
        # the quaternions up to the rounding of their norm (summed in another order), the rest bit for bit
        quaternions = np.r_[root + 3 : root + 7, wrist : wrist + 4]
        np.testing.assert_allclose(qpos[i, quaternions], expected[quaternions], rtol=0, atol=1e-15)
        expected[quaternions] = qpos[i, quaternions]
        np.testing.assert_array_equal(qpos[i], expected, err_msg=f"env {i}")
    # the distributions: ranges, moments, unit quaternions, the positive orthant, the free joint's position kept
    _assert_uniform(qpos[:, a["slide_unlimited"]], -0.3, 0.3, "slide_unlimited")
    _assert_uniform(qpos[:, a["hinge_limited"]], 0.1, 0.2, "hinge_limited")
    np.testing.assert_array_equal(qpos[:, a["slide_limited"]], qpos[:, a["hinge_limited"]])
    normal = qpos[:, a["hinge_unlimited"]]
    assert abs(normal.mean() - 0.5) < 5 * 0.2 / math.sqrt(N_DRAWS) and abs(normal.std() / 0.2 - 1) < 0.1
    np.testing.assert_array_equal(qpos[:, root : root + 3], np.broadcast_to(model.qpos0[root : root + 3], (N_DRAWS, 3)))
    assert not np.array_equal(model.qpos0[root : root + 3], np.zeros(3))
    uniform, positive = qpos[:, root + 3 : root + 7], qpos[:, wrist : wrist + 4]
    for quaternions in (uniform, positive):
        np.testing.assert_allclose(np.linalg.norm(quaternions, axis=1), 1.0, rtol=0, atol=1e-15)
    assert (positive >= 0).all()
    # uniform on rotations: every component has mean 0 and E[q_k^2] = 1/4 (the positive rule does not)
    assert (np.abs(uniform.mean(axis=0)) < 5 * 0.5 / math.sqrt(N_DRAWS)).all()
    np.testing.assert_allclose((uniform**2).mean(axis=0), 0.25, atol=0.04)
    assert (uniform < 0).mean() > 0.4
    assert (env.batch.bind("qvel") == 0).all()
    env.close()


# ------------------------------------------------------------------------------ per-env generators, run state
def _finger_steps() -> list[ResetStep]:
    """dm_control's finger turn, roughly: joints until nothing touches, a target on a ring, a side draw."""
    return [
        UntilContactFree([UniformJoints()]),  # a varying number of draws per env
        DrawDomain("site_pos:target", Ring((0.2, 0.4), 0.13, axes=(0, 2))),
        DrawDomain("geom_pos:ground", Choice(((0.3, Box((-0.1,), (0.1,))), (0.7, Box((-0.5, -0.5), (0.5, 0.5)))))),
    ]


DOMAIN = ["site_pos:target", "geom_pos:ground"]


@pytest.fixture(scope="module")
def finger_envs() -> list[BatchedMujocoEnv]:
    path = dm_control_suite_xml("finger.xml")
    envs = [_env(path, 6, _finger_steps(), seed=10, frame_skip=2) for _ in range(2)]
    yield envs
    for env in envs:
        env.close()


def _snapshot(env: BatchedMujocoEnv) -> dict[str, np.ndarray]:
    out = {"qpos": _qpos(env), "qvel": env.batch.bind("qvel").copy()}
    out.update({name: value.numpy() for name, value in env.domain_values(DOMAIN).items()})
    return out


def _assert_rows(a: dict[str, np.ndarray], b: dict[str, np.ndarray], rows: list[int], what: str) -> None:
    for key in a:
        np.testing.assert_array_equal(a[key][rows], b[key][rows], err_msg=f"{what}: {key}")


def test_an_envs_draws_do_not_depend_on_which_others_reset(finger_envs) -> None:
    full, partial = finger_envs
    full.set_seed(10)  # envs 2 and 3 draw their joints twice, the others once
    partial.set_seed(10)
    full.reset()
    drawn = _snapshot(full)
    before = _snapshot(partial)
    rows = [1, 2, 5]
    partial.reset(TensorDict({"_reset": _mask(6, *rows)}, [6]))
    after = _snapshot(partial)
    _assert_rows(drawn, after, rows, "the envs reset draw as in a full reset")
    _assert_rows(before, after, [0, 3, 4], "the others are untouched")
    # the draws are of the declaration: each env's first contact-free draw, then its target and ground
    model = mujoco.MjModel.from_xml_path(str(dm_control_suite_xml("finger.xml")))
    low = np.where(model.jnt_limited, model.jnt_range[:, 0], -math.pi)
    high = np.where(model.jnt_limited, model.jnt_range[:, 1], math.pi)
    draws = []
    for i, rng in enumerate(generators(10, 6)):
        qpos = model.qpos0.copy()
        draws.append(0)
        while draws[-1] == 0 or _ncon(model, qpos) > 0:
            qpos[model.jnt_qposadr] = rng.uniform(low, high)
            draws[-1] += 1
        np.testing.assert_array_equal(drawn["qpos"][i], qpos, err_msg=f"env {i}")
        angle = rng.uniform(0.0, 2 * math.pi)
        target = model.site("target").pos.copy()
        target[[0, 2]] = 0.2 + 0.13 * math.sin(angle), 0.4 + 0.13 * math.cos(angle)
        np.testing.assert_array_equal(drawn["site_pos:target"][i], target, err_msg=f"env {i}")
        ground = model.geom("ground").pos.copy()
        if rng.random() < 0.3:
            ground[:1] = rng.uniform([-0.1], [0.1])
        else:
            ground[:2] = rng.uniform([-0.5, -0.5], [0.5, 0.5])
        np.testing.assert_array_equal(drawn["geom_pos:ground"][i], ground, err_msg=f"env {i}")
    assert draws == [1, 1, 2, 2, 1, 1]  # the envs drew their joints different numbers of times


def test_set_seed_reproduces_and_another_seed_differs(finger_envs) -> None:
    env = finger_envs[0]
    env.set_seed(3)
    env.reset()
    first = _snapshot(env)
    env.reset()
    assert not np.array_equal(_snapshot(env)["qpos"], first["qpos"])  # the generators moved on
    env.set_seed(3)
    env.reset()
    _assert_rows(first, _snapshot(env), list(range(6)), "set_seed(3) again")
    env.set_seed(4)
    env.reset()
    assert not np.array_equal(_snapshot(env)["site_pos:target"], first["site_pos:target"])


def _episodes(env: BatchedMujocoEnv, rounds: int = 3) -> list[dict[str, np.ndarray]]:
    """Partial resets and steps with fixed actions: each env's state and domain values after every call."""
    out, rng = [], np.random.default_rng(0)
    for k in range(rounds):
        env.reset(TensorDict({"_reset": _mask(6, k % 6, (k + 3) % 6)}, [6]))
        out.append(_snapshot(env))
        action = torch.from_numpy(rng.uniform(-1, 1, (6, env.model.nu)))
        env.step(TensorDict({"action": action}, [6]))
        out.append(_snapshot(env))
    return out


def _assert_same(a: list[dict[str, np.ndarray]], b: list[dict[str, np.ndarray]]) -> None:
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        _assert_rows(x, y, list(range(6)), f"call {k}")


def test_a_loaded_state_dict_continues_the_draws_and_keeps_the_drawn_domain(finger_envs) -> None:
    env, other = finger_envs
    env.set_seed(21)
    env.reset()
    saved = copy.deepcopy(env.state_dict())
    at_save = _snapshot(env)
    expected = _episodes(env)
    other.set_seed(99)
    other.reset()  # other draws, other targets
    assert not np.array_equal(_snapshot(other)["site_pos:target"], at_save["site_pos:target"])
    other.load_state_dict(saved)
    _assert_rows(at_save, _snapshot(other), list(range(6)), "loaded")  # the drawn targets are back
    for i in range(6):  # each env's model holds its drawn values again
        model = other.batch.get_model(i)
        np.testing.assert_array_equal(model.site("target").pos, at_save["site_pos:target"][i], err_msg=f"env {i}")
        np.testing.assert_array_equal(model.geom("ground").pos, at_save["geom_pos:ground"][i], err_msg=f"env {i}")
    _assert_same(_episodes(other), expected)
    # an env of other steps (a ring of another radius) refuses the checkpoint and keeps its own state
    steps = _finger_steps()
    steps[1] = DrawDomain("site_pos:target", Ring((0.2, 0.4), 0.1, axes=(0, 2)))
    another = _env(dm_control_suite_xml("finger.xml"), 6, steps, seed=11, frame_skip=2)
    another.reset()
    before = _snapshot(another)
    with pytest.raises(ValueError, match=r"the saved running episodes are of another simulation \(declaration differ"):
        another.load_state_dict(saved)
    _assert_rows(before, _snapshot(another), list(range(6)), "refused")
    another.close()


def test_copies_and_pickles_are_independent_envs_in_the_same_state(finger_envs) -> None:
    env = finger_envs[0]
    env.set_seed(8)
    env.reset()
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    at_copy = _snapshot(env)
    expected = _episodes(env)
    after = _snapshot(env)
    for each in copies:
        _assert_rows(at_copy, _snapshot(each), list(range(6)), "copied")
        _assert_same(_episodes(each), expected)
        each.reset()  # the copy moves on: the original does not
        _assert_rows(after, _snapshot(env), list(range(6)), "the original")
        each.close()


# ------------------------------------------------------------------------------ domain draws reach the physics
def _assert_physics(env: BatchedMujocoEnv, names: list[str], fields: tuple[str, ...]) -> None:
    """Every env's ``fields`` equal a copy of the model set to its domain values and mj_forward from its state."""
    values = {name: value.numpy() for name, value in env.domain_values(names).items()}
    for i in range(env.num_envs):
        model = reference_model(env.model, {name: value[i] for name, value in values.items()})
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:] = env.batch.bind("qpos")[i], env.batch.bind("qvel")[i]
        mujoco.mj_forward(model, data)
        for field in fields:
            np.testing.assert_array_equal(env.batch.bind(field)[i], getattr(data, field), err_msg=f"env {i} {field}")


def test_a_drawn_target_geom_is_each_envs_own_in_the_physics() -> None:
    """reacher: the target geom on the world body, on a ring (dm_control's reacher), after the arm's joints."""
    steps = [UniformJoints(), DrawDomain("geom_pos:target", Ring((0.0, 0.0), (0.05, 0.2)))]
    env = _env(dm_control_suite_xml("reacher.xml"), 8, steps, seed=2, observation=R.data_field("geom_xpos"))
    out = env.reset()["observation"].numpy().reshape(8, -1, 3)
    model, target = env.model, env.model.geom("target").id
    assert model.geom_bodyid[target] == 0 and model.njnt == 2
    low = np.where(model.jnt_limited, model.jnt_range[:, 0], -math.pi)
    high = np.where(model.jnt_limited, model.jnt_range[:, 1], math.pi)
    values = env.domain_values(["geom_pos:target"])["geom_pos:target"].numpy()
    for i, rng in enumerate(generators(2, 8)):
        np.testing.assert_array_equal(_qpos(env)[i], rng.uniform(low, high), err_msg=f"env {i}")
        angle, radius = rng.uniform(0.0, 2 * math.pi), rng.uniform(0.05, 0.2)
        expected = np.array([radius * math.sin(angle), radius * math.cos(angle), model.geom_pos[target, 2]])
        np.testing.assert_array_equal(values[i], expected, err_msg=f"env {i}")
        np.testing.assert_array_equal(out[i, target], expected, err_msg=f"env {i}")  # world body: xpos = pos
    radii = np.hypot(values[:, 0], values[:, 1])
    assert len(np.unique(radii)) == 8 and 0.05 <= radii.min() and radii.max() < 0.2
    _assert_physics(env, ["geom_pos:target"], ("geom_xpos", "site_xpos", "xpos"))
    # a second reset draws new targets for the envs reset only
    env.reset(TensorDict({"_reset": _mask(8, 2, 5)[:, None]}, [8]))
    now = env.domain_values(["geom_pos:target"])["geom_pos:target"].numpy()
    changed = np.flatnonzero((now != values).any(axis=1)).tolist()
    assert changed == [2, 5]
    _assert_physics(env, ["geom_pos:target"], ("geom_xpos",))
    env.close()


def test_a_drawn_body_pose_is_each_envs_own_in_the_physics() -> None:
    """manipulator: the target body's x, z on a box and its turn about y (dm_control's bring_ball)."""
    steps = [
        DrawDomain("body_pos:target_ball", Box((-0.4, 0.1), (0.4, 0.4), axes=(0, 2))),
        DrawDomain("body_quat:target_ball", AxisAngle((0.0, 1.0, 0.0))),
    ]
    env = _env(dm_control_suite_xml("manipulator.xml"), 6, steps, seed=4)
    env.reset()
    model, body = env.model, env.model.body("target_ball").id
    names = ["body_pos:target_ball", "body_quat:target_ball"]
    values = {name: value.numpy() for name, value in env.domain_values(names).items()}
    for i, rng in enumerate(generators(4, 6)):
        position = model.body_pos[body].copy()
        position[[0, 2]] = rng.uniform([-0.4, 0.1], [0.4, 0.4])
        half = 0.5 * rng.uniform(-math.pi, math.pi)
        np.testing.assert_array_equal(values[names[0]][i], position, err_msg=f"env {i}")
        np.testing.assert_array_equal(values[names[1]][i], [math.cos(half), 0.0, math.sin(half), 0.0])
    _assert_physics(env, names, ("xpos", "xquat", "geom_xpos", "site_xpos"))
    env.close()


def test_a_drawn_field_with_a_range_stays_in_it_and_reaches_each_envs_model() -> None:
    """A free joint's damping (>= 0, 6 values) and gravity (finite): checked as set_domain checks them."""
    steps = [
        DrawDomain("dof_damping:root", Box((0.0,) * 6, (2.0,) * 6)),
        DrawDomain("gravity", Choice(((0.5, Ring((0.0, -9.81), 1.0, axes=(0, 2))), (0.5, Box((-1.0,), (1.0,)))))),
    ]
    env = _env(JOINTS_XML, 6, steps, seed=13)
    env.reset()
    values = {name: value.numpy() for name, value in env.domain_values(["dof_damping:root", "gravity"]).items()}
    for i, rng in enumerate(generators(13, 6)):
        damping, gravity = rng.uniform([0.0] * 6, [2.0] * 6), env.model.opt.gravity.copy()
        if rng.random() < 0.5:
            angle = rng.uniform(0.0, 2 * math.pi)
            gravity[[0, 2]] = math.sin(angle), -9.81 + math.cos(angle)
        else:
            gravity[0] = rng.uniform(-1.0, 1.0)
        np.testing.assert_array_equal(values["dof_damping:root"][i], damping, err_msg=f"env {i}")
        np.testing.assert_array_equal(values["gravity"][i], gravity, err_msg=f"env {i}")
        reference = reference_model(env.model, {name: value[i] for name, value in values.items()})
        model = env.batch.get_model(i)
        np.testing.assert_array_equal(model.dof_damping, reference.dof_damping, err_msg=f"env {i}")
        np.testing.assert_array_equal(model.opt.gravity, reference.opt.gravity, err_msg=f"env {i}")
    env.close()


# ------------------------------------------------------------------------------ contacts
def test_until_contact_free_redraws_each_touching_env_until_it_touches_nothing() -> None:
    n, seed = 32, 6
    env = _env(WALL_XML, n, [UntilContactFree([UniformJoints()])], seed=seed)
    env.reset()
    model, qpos = env.model, _qpos(env)
    first_touching = 0
    for i, rng in enumerate(generators(seed, n)):
        draws = [rng.uniform([-1.0, -1.0], [1.0, 1.0])]
        while _ncon(model, draws[-1]) > 0:
            draws.append(rng.uniform([-1.0, -1.0], [1.0, 1.0]))
        first_touching += len(draws) > 1
        np.testing.assert_array_equal(qpos[i], draws[-1], err_msg=f"env {i}")  # the first draw that is free
        assert _ncon(model, qpos[i]) == 0
    assert first_touching > n / 2  # most first draws touched the wall: the loop ran
    assert (env.batch.bind("ncon") == 0).all()
    env.close()


def test_until_contact_free_on_dm_control_models_leaves_no_contact() -> None:
    """ball_in_cup (the ball drawn on slides inside the cup's range) and finger (every joint drawn)."""
    cases = [
        ("ball_in_cup.xml", [UntilContactFree([UniformJoints({"ball_x": (-0.2, 0.2), "ball_z": (0.2, 0.5)})])]),
        ("finger.xml", [UntilContactFree([UniformJoints()])]),
    ]
    for name, steps in cases:
        path = dm_control_suite_xml(name)
        model = mujoco.MjModel.from_xml_path(str(path))
        env = _env(path, 16, steps, seed=1)
        env.reset()
        qpos = _qpos(env)
        assert all(_ncon(model, qpos[i]) == 0 for i in range(16)), name
        env.close()


def test_exhausted_attempts_raise_naming_the_envs() -> None:
    n, seed = 8, 6
    env = _env(WALL_XML, n, [UntilContactFree([UniformJoints()], attempts=2)], seed=seed)
    model = env.model
    touching = []
    for i, rng in enumerate(generators(seed, n)):
        if all(_ncon(model, rng.uniform([-1.0, -1.0], [1.0, 1.0])) > 0 for _ in range(2)):
            touching.append(i)
    assert touching and len(touching) < n
    with pytest.raises(RuntimeError, match=re.escape(f"UntilContactFree: envs {touching} still touched something")):
        env.reset()
    env.close()


def test_raise_until_contact_free_finds_the_first_free_height_of_the_accumulated_steps() -> None:
    """quadruped: a random orientation, then raised from ``start`` by ``step`` (z += step) until it touches nothing."""
    n, seed, start, step = 4, 9, 0.05, 0.02
    steps = [RandomOrientation("root"), RaiseUntilContactFree("root", step=step, start=start)]
    path = dm_control_suite_xml("quadruped.xml")
    env = _env(path, n, steps, seed=seed)
    env.reset()
    model, qpos = env.model, _qpos(env)
    for i, rng in enumerate(generators(seed, n)):
        state = model.qpos0.copy()
        q = rng.standard_normal(4)
        state[3:7] = q / np.linalg.norm(q)
        state[2] = start
        while _ncon(model, state) > 0:
            state[2] += step
        np.testing.assert_array_equal(qpos[i], state, err_msg=f"env {i}")
        assert state[2] > start  # raised at least once
        below = state.copy()
        below[2] -= step
        assert _ncon(model, below) > 0 and _ncon(model, state) == 0
    env.close()
    # a start that touches nothing is kept as it is
    env = _env(path, 2, [RaiseUntilContactFree("root", step=step, start=1.5)], seed=seed)
    env.reset()
    assert (_qpos(env)[:, 2] == 1.5).all()
    env.close()


# ------------------------------------------------------------------------------ settling
@pytest.mark.parametrize("stage", ["velocity", "step"])
def test_settle_steps_the_drawn_state_with_zero_controls_and_restarts_the_clock(stage: str) -> None:
    """cheetah (dm_control draws its limited joints and steps 200 times): the state is MjData's after mj_step."""
    path, n, seed, substeps = dm_control_suite_xml("cheetah.xml"), 3, 12, 30
    model = mujoco.MjModel.from_xml_path(str(path))
    limited = [model.joint(j).name for j in range(model.njnt) if model.jnt_limited[j]]
    env = _env(path, n, [UniformJoints(limited), Settle(substeps)], seed=seed, stage=stage, frame_skip=5)
    env.reset()
    low, high = model.jnt_range[model.jnt_limited.astype(bool)].T
    datas = []
    for i, rng in enumerate(generators(seed, n)):
        data = mujoco.MjData(model)
        data.qpos[[_adr(model, j) for j in limited]] = rng.uniform(low, high)
        mujoco.mj_step(model, data, nstep=substeps)  # ctrl: zeros
        data.time = 0.0
        assert np.abs(data.qvel).max() > 0  # it moved
        for field in ("qpos", "qvel", "qacc_warmstart", "time"):
            np.testing.assert_array_equal(env.batch.bind(field)[i], getattr(data, field), err_msg=f"env {i} {field}")
        datas.append(data)
    # the next step continues from there, as the MjData does
    out = env.step(TensorDict({"action": torch.full((n, model.nu), 0.3, dtype=torch.float64)}, [n]))["next"]
    for i, data in enumerate(datas):
        data.ctrl[:] = 0.3
        mujoco.mj_step(model, data, nstep=5)
        np.testing.assert_array_equal(out["qpos"][i].numpy(), data.qpos, err_msg=f"env {i}")
        np.testing.assert_array_equal(out["qvel"][i].numpy(), data.qvel, err_msg=f"env {i}")
    env.close()


def test_settle_from_a_keyframe_holds_its_controls() -> None:
    """The shipped quadruped's "home" keyframe holds its servos' targets: the settling steps keep them."""
    path, substeps = model_path("quadruped"), 20
    model = mujoco.MjModel.from_xml_path(str(path))
    key = model.key("home")
    assert (key.ctrl != 0).any()
    env = BatchedMujocoEnv(
        path, 2, observation=R.joint_pos(), resets=Resets(keyframe="home", steps=[Settle(substeps)]), seed=0
    )
    env.reset()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, key.id)
    mujoco.mj_step(model, data, nstep=substeps)
    for i in range(2):
        for field in ("qpos", "qvel", "ctrl"):
            np.testing.assert_array_equal(env.batch.bind(field)[i], getattr(data, field), err_msg=f"env {i} {field}")
        assert env.batch.bind("time")[i] == 0.0
    env.close()


# ------------------------------------------------------------------------------ resets to given states
def test_resets_to_given_states_skip_the_state_draws_and_still_draw_the_domain() -> None:
    n, seed = 4, 7
    steps = [UniformJoints(), DrawDomain("geom_pos:post", Box((1.5, -0.5), (2.5, 0.5), axes=(0, 2))), Settle(3)]
    env = _env(WALL_XML, n, steps, seed=seed, observation={"qpos": R.joint_pos(), "time": R.time()})
    model = env.model
    given = torch.tensor([[0.9, 0.95], [-0.95, 0.9], [0.95, -0.95], [-0.9, -0.9]], dtype=torch.float64)
    post = model.geom("post").pos

    def expected_post(rng: np.random.Generator) -> np.ndarray:
        value = post.copy()
        value[[0, 2]] = rng.uniform([1.5, -0.5], [2.5, 0.5])
        return value

    # set_reset_states for envs 1 and 3: they start there, not settled, and draw only the post (their first draw)
    env.set_reset_states(given, mask=_mask(n, 1, 3))
    out = env.reset()
    values = env.domain_values(["geom_pos:post"])["geom_pos:post"].numpy()
    for i, rng in enumerate(generators(seed, n)):
        if i in (1, 3):
            np.testing.assert_array_equal(out["qpos"][i].numpy(), given[i].numpy(), err_msg=f"env {i}")
            assert out["time"][i, 0] == 0.0 and (env.batch.bind("qvel")[i] == 0).all()
        else:
            rng.uniform([-1.0, -1.0], [1.0, 1.0])  # the joints, then the post
            assert not np.array_equal(out["qpos"][i].numpy(), given[i].numpy())
        np.testing.assert_array_equal(values[i], expected_post(rng), err_msg=f"env {i}")
    _assert_physics(env, ["geom_pos:post"], ("geom_xpos",))
    # the reset tensordict's states for the envs of its mask: the same rule
    previous = values.copy()
    reset = TensorDict({"_reset": _mask(n, 0, 2)[:, None], "reset_qpos": given}, [n])
    out = env.reset(reset)
    values = env.domain_values(["geom_pos:post"])["geom_pos:post"].numpy()
    for i, rng in enumerate(generators(seed, n)):
        if i in (0, 2):
            rng.uniform([-1.0, -1.0], [1.0, 1.0])  # the first reset's draws
            expected_post(rng)
            np.testing.assert_array_equal(out["qpos"][i].numpy(), given[i].numpy(), err_msg=f"env {i}")
            np.testing.assert_array_equal(values[i], expected_post(rng), err_msg=f"env {i}")
        else:
            np.testing.assert_array_equal(values[i], previous[i], err_msg=f"env {i}")
    _assert_physics(env, ["geom_pos:post"], ("geom_xpos",))
    env.close()


def test_a_reset_to_given_states_draws_the_domain_inside_until_contact_free_once() -> None:
    """A target drawn inside the rejection loop (dm_control's manipulator) is drawn once for a given state."""
    n, seed = 3, 11
    draw = DrawDomain("geom_pos:post", Box((1.5, -0.5), (2.5, 0.5), axes=(0, 2)))
    env = _env(WALL_XML, n, [UntilContactFree([UniformJoints(), draw])], seed=seed, observation=R.joint_pos())
    given = torch.tensor([[0.9, 0.95]] * n, dtype=torch.float64)
    env.set_reset_states(given)
    out = env.reset()
    values = env.domain_values(["geom_pos:post"])["geom_pos:post"].numpy()
    post = env.model.geom("post").pos
    for i, rng in enumerate(generators(seed, n)):
        expected = post.copy()
        expected[[0, 2]] = rng.uniform([1.5, -0.5], [2.5, 0.5])  # the post only: no joint draw, no rejection
        np.testing.assert_array_equal(values[i], expected, err_msg=f"env {i}")
        np.testing.assert_array_equal(out["observation"][i].numpy(), given[i].numpy())
    env.close()


# ------------------------------------------------------------------------------ bad declarations
def _bad_steps() -> list[tuple[Callable[[], Any], type[Exception], str]]:
    """(what builds the env or the step, the error, a pattern of its message), on JOINTS_XML unless said."""

    def env(*steps: Any, xml: str = JOINTS_XML) -> Callable[[], Any]:
        return lambda: _env(xml, 2, list(steps))

    return [
        (env(UniformJoints(["hinge_limitd"])), ValueError, r"UniformJoints joints: .*no joint 'hinge_limitd'; did "
         r"you mean 'hinge_limited'"),
        (env(UniformJoints(["wrist"])), ValueError, r"UniformJoints joints: joint 'wrist' is not a hinge or slide"),
        (env(UniformJoints(["slide_unlimited"])), ValueError, r"slide 'slide_unlimited' is unlimited: give its range"),
        (env(UniformJoints({"hinge_limited": (1.0, -1.0)})), ValueError, r"joints\['hinge_limited'\] must have low "
         r"<= high, got \(1.0, -1.0\)"),
        (env(UniformJoints({"hinge_limited": (0.0, math.nan)})), TypeError, r"joints\['hinge_limited'\]\[1\] must "
         r"be a finite real number, got nan"),
        (env(UniformJoints("hinge_limited")), TypeError, r"UniformJoints joints must be a sequence of joint names"),
        (env(NormalJoints({"hinge_limited": (0.0, -0.1)})), ValueError, r"NormalJoints joints\['hinge_limited'\]: "
         r"the std must be >= 0, got -0.1"),
        (env(NormalJoints({"root": (0.0, 0.1)})), ValueError, r"NormalJoints joints: joint 'root' is not a hinge"),
        (env(NormalJoints({})), TypeError, r"NormalJoints joints must map joint names to \(mean, std\)"),
        (env(RandomOrientation("hinge_limited")), ValueError, r"RandomOrientation joint: joint 'hinge_limited' is not "
         r"a free or ball joint"),
        (env(RandomOrientation("roots")), ValueError, r"RandomOrientation joint: .*no joint 'roots'; did you mean "
         r"'root'"),
        (env(RandomOrientation("root", "gaussian")), ValueError, r"distribution must be one of \['uniform', "
         r"'positive'\], got 'gaussian'"),
        (env(CopyJoints({"hinge_limited": "slid_limited"})), ValueError, r"CopyJoints joints: .*no joint "
         r"'slid_limited'; did you mean 'slide_limited'"),
        (env(CopyJoints({"hinge_limited": 3})), TypeError, r"CopyJoints joints\['hinge_limited'\] must be a joint "
         r"name, got 3"),
        (env(DrawDomain("geom_pos:posts", Box((0.0,), (1.0,))), xml=WALL_XML), ValueError, r"DrawDomain field: the "
         r"model offers no domain field 'geom_pos:posts'; did you mean 'geom_pos:post'"),
        (env(DrawDomain("geom_pos:post", AxisAngle((0.0, 0.0, 1.0))), xml=WALL_XML), ValueError, r"AxisAngle draws "
         r"a quaternion; domain field 'geom_pos:post' has shape \(3,\)"),
        (env(DrawDomain("geom_pos:post", Box((0.0,) * 4, (1.0,) * 4)), xml=WALL_XML), ValueError, r"Box axes "
         r"range\(0, 4\) do not index domain field 'geom_pos:post' of shape \(3,\)"),
        (env(DrawDomain("geom_pos:post", Ring((0.0, 0.0), 1.0, axes=(0, 3))), xml=WALL_XML), ValueError, r"Ring axes "
         r"\(0, 3\) do not index domain field 'geom_pos:post'"),
        (env(DrawDomain("geom_pos:post", "box"), xml=WALL_XML), TypeError, r"DrawDomain sampler must be a Sampler, "
         r"got str"),
        # draws set_domain would refuse: a negative damping (of a free joint: 6 values), from any sampler
        (env(DrawDomain("dof_damping:root", Box((-0.5,), (1.0,)))), ValueError, r"DrawDomain\(field='dof_damping:"
         r"root', .*\) can write -0.5 into 'dof_damping:root' \(damping of joint 'root' \(per dof\)\), which must "
         r"be in \[0.0, inf\); narrow the sampler"),
        (env(DrawDomain("dof_damping:root", Ring((0.5, 0.5), (0.1, 0.6)))), ValueError, r"can write -0.09999+\d* "
         r"into 'dof_damping:root'"),
        (env(DrawDomain("dof_damping:root", Choice(((0.9, Box((0.0,), (1.0,))), (0.1, Box((-1.0,), (0.0,))))))),
         ValueError, r"can write -1.0 into 'dof_damping:root'"),
        (lambda: Box((0.0,), (1.0, 2.0)), ValueError, r"Box needs low <= high with one entry per axis"),
        (lambda: Box((1.0,), (0.0,)), ValueError, r"Box needs low <= high"),
        (lambda: Box((0.0, 0.0), (1.0, 1.0), axes=(0,)), ValueError, r"Box axes \(one per entry of low\) must be 2 "
         r"distinct indices \(ints >= 0\), got \(0,\)"),
        (lambda: Box((0.0, 0.0), (1.0, 1.0), axes=(2, 2)), ValueError, r"Box axes .* must be 2 distinct indices"),
        (lambda: Box((0.0,), (1.0,), axes=0), ValueError, r"Box axes .* must be 1 distinct indices .*got 0"),
        (lambda: Box(0.0, 1.0), TypeError, r"Box low must be a non-empty sequence of finite numbers, got 0.0"),
        (lambda: Box((0.0,), (math.inf,)), TypeError, r"Box high must be a finite real number, got inf"),
        (lambda: Ring((0.0, 0.0), 0.1, axes=(1, 1)), ValueError, r"Ring axes must be 2 distinct indices \(ints >= "
         r"0\), got \(1, 1\)"),
        (lambda: Ring((0.0, 0.0), 0.1, axes=(0,)), ValueError, r"Ring axes must be 2 distinct indices"),
        (lambda: Ring((0.0, 0.0), math.inf), TypeError, r"Ring radius must be a finite real number, got inf"),
        (lambda: Ring((0.0, 0.0), -0.1), ValueError, r"Ring radius must be >= 0 \(low <= high\), got -0.1"),
        (lambda: Ring((0.0, 0.0), (0.2, 0.1)), ValueError, r"Ring radius must be >= 0 \(low <= high\)"),
        (lambda: Ring((0.0,), 0.1), TypeError, r"Ring centre must be a pair of finite numbers"),
        (lambda: AxisAngle((1.0, 1.0, 0.0)), ValueError, r"AxisAngle axis must be a unit 3-vector"),
        (lambda: Choice(((0.5, Box((0.0,), (1.0,))), (0.4, Box((0.0,), (1.0,))))), ValueError, r"Choice "
         r"probabilities must be >= 0 and sum to 1, got \[0.5, 0.4\]"),
        (lambda: Choice(((1.0, "box"),)), TypeError, r"Choice options must be \(probability, Sampler\) pairs"),
        (env(UntilContactFree([])), TypeError, r"UntilContactFree steps must be a non-empty sequence of ResetSteps, "
         r"got \[\]"),
        (env(UntilContactFree(UniformJoints())), TypeError, r"UntilContactFree steps must be a non-empty sequence of "
         r"ResetSteps, got UniformJoints\(joints=None\)"),
        (env(UntilContactFree([UniformJoints(), "again"])), TypeError, r"UntilContactFree steps must be ResetSteps"),
        (env(UntilContactFree([UniformJoints()], attempts=0)), ValueError, r"UntilContactFree attempts must be a "
         r"positive int, got 0"),
        (env(UntilContactFree([UniformJoints(["wrist"])])), ValueError, r"joint 'wrist' is not a hinge or slide"),
        (env(RaiseUntilContactFree("wrist")), ValueError, r"RaiseUntilContactFree joint: joint 'wrist' is not a "
         r"free joint"),
        (env(RaiseUntilContactFree("root", step=0.0)), ValueError, r"RaiseUntilContactFree step must be > 0, got 0.0"),
        (env(RaiseUntilContactFree("root", step=math.inf)), TypeError, r"RaiseUntilContactFree step must be a finite"),
        (env(RaiseUntilContactFree("root", attempts=0)), ValueError, r"RaiseUntilContactFree attempts must be a "
         r"positive int, got 0"),
        (env(Settle(0)), ValueError, r"Settle substeps must be a positive int, got 0"),
        (env(Settle(True)), ValueError, r"Settle substeps must be a positive int, got True"),
        (lambda: Resets(steps=[UniformJoints(), "settle"]), TypeError, r"Resets steps must hold reset steps "
         r"\(torchtasks.envs.reset_steps\), got str"),
        (lambda: Resets(steps=UniformJoints()), TypeError, r"Resets steps must be a sequence of reset steps"),
    ]  # fmt: skip


def test_bad_steps_are_refused_naming_the_argument() -> None:
    cases = _bad_steps()
    for make, error, pattern in cases:
        with pytest.raises(error, match=pattern):
            make()
