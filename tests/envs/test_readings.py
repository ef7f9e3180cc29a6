"""Every reading kind equals MuJoCo's own function for it, on states of per-env MjData stepped with random controls.

The models: a small inline robot with one sensor of each type worth covering, dm_control's suite models (found on
disk without importing dm_control) and Gymnasium's assets. Each env has its own MjModel copy (masses, gravity and
qpos0 differ per env) so that a reading reading a per-env model field from the wrong env is caught. ``compute`` gets
the arrays stacked from the envs' MjData (and MjModel fields), as ``mujoco.batch.Batch.bind`` gives them.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import pickle
import warnings
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from model_files import dm_control_suite_xml, gymnasium_asset  # noqa: E402
from torchtasks.envs import readings as R  # noqa: E402
from torchtasks.envs._mujoco_log import quiet_model_loading  # noqa: E402
from torchtasks.envs.mujoco_model import load_model  # noqa: E402

NUM_ENVS = 4
STEPS = 60

ROBOT = """
<mujoco model="sensor robot">
  <option timestep="0.004"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <body name="torso" pos="0 0 .25">
      <freejoint name="root"/>
      <geom name="torso_geom" type="box" size=".15 .08 .04"/>
      <site name="imu" pos=".05 .01 .02" quat=".9 .1 .2 .3"/>
      <site name="touch_zone" type="box" size=".16 .09 .05"/>
      <body name="thigh" pos=".15 0 0">
        <joint name="hip" axis="0 1 0" range="-1 1" damping=".1"/>
        <geom type="capsule" fromto="0 0 0 .1 0 -.15" size=".02"/>
        <body name="shin" pos=".1 0 -.15">
          <joint name="knee" axis="0 1 0" range="-2 0"/>
          <geom type="capsule" fromto="0 0 0 0 0 -.12" size=".02"/>
          <site name="foot" pos="0 0 -.12" size=".025"/>
        </body>
      </body>
      <body name="arm" pos="-.15 0 0">
        <joint name="shoulder" type="ball" damping=".05"/>
        <geom type="capsule" fromto="0 0 0 -.1 0 -.12" size=".02"/>
        <body name="slider" pos="-.1 0 -.12" quat=".8 .2 .1 .3">
          <joint name="slide" type="slide" axis="0 0 1" range="-.05 .05"/>
          <geom type="sphere" size=".03" pos=".01 .02 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="hip_motor" joint="hip" gear="5" ctrlrange="-1 1"/>
    <position name="knee_servo" joint="knee" kp="10" ctrlrange="-2 0"/>
    <motor name="slide_motor" joint="slide" gear="2" ctrlrange="-1 1"/>
  </actuator>
  <sensor>
    <jointpos name="hip_pos" joint="hip"/>
    <jointvel name="knee_vel" joint="knee"/>
    <ballquat name="shoulder_quat" joint="shoulder"/>
    <ballangvel name="shoulder_angvel" joint="shoulder"/>
    <framepos name="torso_pos" objtype="xbody" objname="torso"/>
    <framequat name="imu_quat" objtype="site" objname="imu"/>
    <framexaxis name="shin_xaxis" objtype="body" objname="shin"/>
    <framelinvel name="torso_linvel" objtype="xbody" objname="torso"/>
    <frameangvel name="torso_angvel" objtype="xbody" objname="torso"/>
    <framelinacc name="torso_linacc" objtype="body" objname="torso"/>
    <frameangacc name="torso_angacc" objtype="body" objname="torso"/>
    <gyro name="imu_gyro" site="imu"/>
    <velocimeter name="imu_vel" site="imu"/>
    <accelerometer name="imu_acc" site="imu"/>
    <rangefinder name="imu_range" site="imu"/>
    <touch name="torso_touch" site="touch_zone"/>
    <force name="foot_force" site="foot"/>
    <torque name="foot_torque" site="foot"/>
    <subtreecom name="torso_com" body="torso"/>
    <subtreelinvel name="torso_subtree_vel" body="torso"/>
    <subtreeangmom name="torso_angmom" body="torso"/>
    <actuatorpos name="hip_motor_pos" actuator="hip_motor"/>
    <actuatorvel name="knee_servo_vel" actuator="knee_servo"/>
    <actuatorfrc name="hip_motor_frc" actuator="hip_motor"/>
    <jointactuatorfrc name="knee_actuator_frc" joint="knee"/>
    <jointlimitpos name="knee_limit_pos" joint="knee"/>
    <clock name="clock"/>
  </sensor>
  <keyframe>
    <key name="crouch" qpos="0 0 .22 1 0 0 0 .4 -.8 1 0 0 0 .01"/>
  </keyframe>
</mujoco>
"""

#: the models: name -> how to find them (a test of a model that is absent is skipped)
MODELS = {
    "robot": lambda: ROBOT,
    "dm_control quadruped": lambda: dm_control_suite_xml("quadruped.xml"),
    "dm_control humanoid": lambda: dm_control_suite_xml("humanoid.xml"),
    "dm_control walker": lambda: dm_control_suite_xml("walker.xml"),
    "dm_control cheetah": lambda: dm_control_suite_xml("cheetah.xml"),
    "gymnasium ant": lambda: gymnasium_asset("ant.xml"),
    "gymnasium humanoid": lambda: gymnasium_asset("humanoid.xml"),
    "gymnasium hopper": lambda: gymnasium_asset("hopper.xml"),
}


#: dm_control's suite models of test_composites_equal_dm_controls_numpy_expressions (their states need not touch)
SUITE_MODELS = {
    "dm_control finger": lambda: dm_control_suite_xml("finger.xml"),
    "dm_control manipulator": lambda: dm_control_suite_xml("manipulator.xml"),
    "dm_control hopper": lambda: dm_control_suite_xml("hopper.xml"),
    "dm_control swimmer": lambda: dm_control_suite_xml("swimmer.xml"),
}


@contextmanager
def _quiet() -> Iterator[None]:
    """Hide MuJoCo 4's deprecation of dm_control's cheetah.xml ``settotalmass`` (a file no one here wrote)."""
    with quiet_model_loading(), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*compiler attribute 'settotalmass' is deprecated")
        yield


def _spec(source: str | Path) -> mujoco.MjSpec:
    with _quiet():
        if isinstance(source, str):
            return mujoco.MjSpec.from_string(source)
        return mujoco.MjSpec.from_file(str(source))


def _with_contact_sensor(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """The model with one framelinacc sensor added, which makes mj_forward fill cfrc_ext (what the env does)."""
    with _quiet():
        body = mujoco.mj_id2name(spec.compile(), mujoco.mjtObj.mjOBJ_BODY, 1)
        added = spec.add_sensor()
        added.type = mujoco.mjtSensor.mjSENS_FRAMELINACC
        added.objtype = mujoco.mjtObj.mjOBJ_XBODY
        added.objname = body
        added.name = "__contact_forces"
        return spec.compile()


def _per_env(model: mujoco.MjModel, env: int) -> mujoco.MjModel:
    """Env ``env``'s copy of the model: its own masses (and subtree masses), gravity and qpos0."""
    own = copy.deepcopy(model)
    own.body_mass[1:] *= 1 + 0.1 * env * np.linspace(0.5, 1.5, model.nbody - 1)
    own.opt.gravity[:] = model.opt.gravity + np.array([0.3 * env, -0.2 * env, 0.1 * env])
    own.qpos0[:] = model.qpos0
    hinges = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    own.qpos0[model.jnt_qposadr[hinges]] += 0.01 * env
    mujoco.mj_setConst(own, mujoco.MjData(own))
    return own


@dataclass
class World:
    """``NUM_ENVS`` envs of a model: per-env models and data after random steps and an mj_forward."""

    name: str
    models: list[mujoco.MjModel]
    datas: list[mujoco.MjData]
    actions: np.ndarray
    #: the same states in the model with an added framelinacc sensor, after mj_forward (cfrc_ext filled)
    sensed: list[mujoco.MjData]

    @property
    def model(self) -> mujoco.MjModel:
        return self.models[0]

    def arrays(self, resolved: R.Resolved, *, contacts: bool = False) -> dict[str, np.ndarray]:
        """The bound arrays ``resolved`` reads, stacked over the envs (cfrc_ext from the sensed copies)."""
        arrays = {}
        for name in resolved.fields:
            datas = self.sensed if name == "cfrc_ext" and contacts else self.datas
            arrays[name] = np.stack([np.asarray(getattr(data, name), dtype=np.float64) for data in datas])
        for name in resolved.model_fields:
            arrays["model." + name] = np.stack([_model_field(model, name) for model in self.models])
        if resolved.action:
            arrays["action"] = self.actions.copy()
        return arrays


def _model_field(model: mujoco.MjModel, name: str) -> np.ndarray:
    owner = model.opt if name.startswith("opt.") else model
    return np.array(getattr(owner, name.removeprefix("opt.")), dtype=np.float64)


def _build_world(name: str) -> World:
    source = {**MODELS, **SUITE_MODELS}[name]()
    with _quiet():
        base = load_model(source)
    with_sensor = _with_contact_sensor(_spec(source))
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    models, sensed_models, datas, sensed, actions = [], [], [], [], []
    low, high = base.actuator_ctrlrange.T
    limited = base.actuator_ctrllimited.astype(bool)
    low, high = np.where(limited, low, -1.0), np.where(limited, high, 1.0)
    for env in range(NUM_ENVS):
        model, model_sensed = _per_env(base, env), _per_env(with_sensor, env)
        data = mujoco.MjData(model)
        if model.nkey:
            mujoco.mj_resetDataKeyframe(model, data, 0)
        data.qpos[:] += rng.uniform(-0.05, 0.05, model.nq)
        data.qvel[:] = rng.normal(0, 0.5, model.nv)
        for _ in range(STEPS):
            data.ctrl[:] = rng.uniform(low, high)
            mujoco.mj_step(model, data)
        action = rng.uniform(low, high)
        data.ctrl[:] = action
        mujoco.mj_forward(model, data)
        state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_INTEGRATION))
        mujoco.mj_getState(model, data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        copied = mujoco.MjData(model_sensed)
        mujoco.mj_setState(model_sensed, copied, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(model_sensed, copied)
        models.append(model)
        sensed_models.append(model_sensed)
        datas.append(data)
        sensed.append(copied)
        actions.append(action)
    return World(name, models, datas, np.array(actions), sensed)


#: the worlds, each built once for the tests that only read them
_shared_world = functools.cache(_build_world)


@pytest.fixture(scope="module", params=list(MODELS))
def world(request: pytest.FixtureRequest) -> World:
    return _shared_world(request.param)


# --------------------------------------------------------------------------------------------- MuJoCo's references


def _object_velocity(model, data, objtype, body: int, local: bool) -> np.ndarray:
    result = np.zeros(6)
    mujoco.mj_objectVelocity(model, data, objtype, body, result, int(local))
    return result


def _projected_gravity(model, data, body: int) -> np.ndarray:
    direction = model.opt.gravity.copy()
    mujoco.mju_normalize3(direction)
    result = np.zeros(3)
    mujoco.mju_mulMatTVec3(result, data.xmat[body], direction)
    return result


def _subtree_linvel(model, data, body: int) -> np.ndarray:
    mujoco.mj_subtreeVel(model, data)
    return data.subtree_linvel[body].copy()


def _post_constraint_forces(model, data, bodies: list[int]) -> np.ndarray:
    copied = copy.copy(data)
    mujoco.mj_rnePostConstraint(model, copied)
    return copied.cfrc_ext[bodies].ravel()


def _names(model, kind: str) -> list[str]:
    count = {"body": model.nbody, "joint": model.njnt, "site": model.nsite, "sensor": model.nsensor}.get(kind)
    count = model.ngeom if count is None else count
    obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "joint": mujoco.mjtObj.mjOBJ_JOINT}.get(kind)
    obj = obj or {"site": mujoco.mjtObj.mjOBJ_SITE, "sensor": mujoco.mjtObj.mjOBJ_SENSOR}.get(kind)
    obj = obj or {"geom": mujoco.mjtObj.mjOBJ_GEOM}[kind]
    return [name for name in (mujoco.mj_id2name(model, obj, i) for i in range(count)) if name]


def _in_frame(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """``vector`` in the axes of the frame of row-major rotation ``matrix`` (MuJoCo's mju_mulMatTVec3)."""
    result = np.zeros(3)
    mujoco.mju_mulMatTVec3(result, matrix, vector)
    return result


def _norm3(vector: np.ndarray) -> float:
    return mujoco.mju_norm3(np.ascontiguousarray(vector, dtype=np.float64))


def _composite_cases(world: World):
    """(reading, its value from the raw MjData fields for env i) for difference, elementwise and norm, composed of
    the other kinds: in a body, geom and site frame, with index and clip, nested, and reading per-env model fields
    and the last action through their inputs (contact forces: test_composites_unite_what_their_inputs_read)."""
    model = world.model
    bodies = [name for name in _names(model, "body") if model.body(name).id > 0]
    first, last = bodies[0], bodies[-1]
    f, t = model.body(first).id, model.body(last).id  # the first body and the last (a tip)
    yield (
        R.difference(R.body_pos(last), R.body_pos(first), frame=f"body:{first}"),
        lambda m, d, i: _in_frame(d.xmat[f], d.xpos[t] - d.xpos[f]),
    )
    yield (
        R.difference(R.body_pos(last, point="com"), R.subtree_com(first), index=(2, 0)),
        lambda m, d, i: (d.xipos[t] - d.subtree_com[f])[[2, 0]],
    )
    yield (
        R.difference(R.subtree_lin_vel(first), R.mass_centre()),
        lambda m, d, i: _subtree_linvel(m, d, f) - np.sum(m.body_mass[:, None] * d.xipos, 0) / np.sum(m.body_mass),
    )
    yield (
        R.norm(R.difference(R.body_pos(last), R.body_pos(first)), offset=-0.07),
        lambda m, d, i: np.array([_norm3(d.xpos[t] - d.xpos[f]) - 0.07]),
    )
    yield (
        R.norm(R.difference(R.body_pos(last), R.body_pos(first), index=(0, 2))),
        lambda m, d, i: np.array([np.sqrt((d.xpos[t, 0] - d.xpos[f, 0]) ** 2 + (d.xpos[t, 2] - d.xpos[f, 2]) ** 2)]),
    )
    yield (
        R.elementwise(R.norm(R.body_pos(last, point="com")), "log1p"),
        lambda m, d, i: np.log1p([_norm3(d.xipos[t])]),
    )
    yield (
        R.elementwise(R.subtree_lin_vel(first), "arcsinh", clip=(-0.5, 0.5)),
        lambda m, d, i: np.clip(np.arcsinh(_subtree_linvel(m, d, f)), -0.5, 0.5),
    )
    hinges = [j for j in _names(model, "joint") if model.joint(j).type == mujoco.mjtJoint.mjJNT_HINGE]
    q = [model.joint(j).qposadr[0] for j in hinges[::-1]]
    yield (
        R.elementwise(R.joint_pos(*hinges[::-1]), "sin_cos"),
        lambda m, d, i: np.column_stack([np.sin(d.qpos[q]), np.cos(d.qpos[q])]).ravel(),
    )
    yield (
        R.elementwise(R.joint_pos(*hinges), "sin_cos", index=(1,)),
        lambda m, d, i: np.cos(d.qpos[[model.joint(hinges[0]).qposadr[0]]]),
    )
    if model.nu:
        yield R.elementwise(R.last_action(), "arcsinh"), lambda m, d, i: np.arcsinh(world.actions[i])
    geoms = _names(model, "geom")
    if geoms:  # the frame: the last named geom (on a moving body in every model here)
        a, g = model.geom(geoms[0]).id, model.geom(geoms[-1]).id
        yield (
            R.difference(R.geom_pos(geoms[0]), R.geom_pos(geoms[-1]), frame=f"geom:{geoms[-1]}"),
            lambda m, d, i: _in_frame(d.geom_xmat[g], d.geom_xpos[a] - d.geom_xpos[g]),
        )
        yield (
            R.difference(R.geom_pos(geoms[-1]), R.body_pos(last), frame=f"geom:{geoms[-1]}", index=(1,)),
            lambda m, d, i: _in_frame(d.geom_xmat[g], d.geom_xpos[g] - d.xpos[t])[[1]],
        )
    sites = _names(model, "site")
    if sites:
        s = model.site(sites[0]).id
        yield (
            R.difference(
                R.body_pos(last, point="com"), R.site_pos(sites[0]), frame=f"site:{sites[0]}", clip=(-0.1, 0.1)
            ),
            lambda m, d, i: np.clip(_in_frame(d.site_xmat[s], d.xipos[t] - d.site_xpos[s]), -0.1, 0.1),
        )
    touch = [n for n in _names(model, "sensor") if model.sensor(n).type == mujoco.mjtSensor.mjSENS_TOUCH]
    for name in touch[:2]:
        yield R.elementwise(R.sensor(name), "log1p"), lambda m, d, i, name=name: np.log1p(d.sensor(name).data)


_XBODY, _BODY = mujoco.mjtObj.mjOBJ_XBODY, mujoco.mjtObj.mjOBJ_BODY


def _cases(world: World):
    """(reading, MuJoCo's value for env i, exact) for every kind on every named object of the world's model."""
    model = world.model
    joints = _names(model, "joint")
    hinge_like = [
        j for j in joints if model.joint(j).type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    ]
    yield R.joint_pos(), lambda m, d, i: d.qpos.copy()
    yield R.joint_pos(*joints), lambda m, d, i: np.concatenate([d.joint(j).qpos for j in joints])
    if hinge_like:
        yield (
            R.joint_pos(*hinge_like, relative_to="qpos0"),
            lambda m, d, i: np.concatenate([d.joint(j).qpos - m.joint(j).qpos0 for j in hinge_like]),
        )
    if model.nkey and mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_KEY, 0) and hinge_like:
        key = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_KEY, 0)
        yield (
            R.joint_pos(*hinge_like, relative_to=key),
            lambda m, d, i: np.array([d.joint(j).qpos[0] - m.key(key).qpos[m.joint(j).qposadr[0]] for j in hinge_like]),
        )
    yield R.joint_vel(), lambda m, d, i: d.qvel.copy()
    yield R.joint_vel(*joints[::-1]), lambda m, d, i: np.concatenate([d.joint(j).qvel for j in joints[::-1]])
    if model.nu:
        actuators = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(model.nu)]
        named = [a for a in actuators if a][::-1]
        yield R.actuator_ctrl(), lambda m, d, i: d.ctrl.copy()
        yield R.actuator_force(), lambda m, d, i: d.actuator_force.copy()
        if named:
            yield R.actuator_ctrl(*named), lambda m, d, i: np.array([d.actuator(a).ctrl[0] for a in named])
            yield R.actuator_force(*named), lambda m, d, i: np.array([d.actuator(a).force[0] for a in named])
        yield R.last_action(), lambda m, d, i: world.actions[i]
        yield R.last_action(clip=(-0.5, 0.25)), lambda m, d, i: np.clip(world.actions[i], -0.5, 0.25)
    for name in _names(model, "sensor"):
        yield R.sensor(name), lambda m, d, i, name=name: d.sensor(name).data.copy()
    for name in _names(model, "body"):
        b = model.body(name).id
        yield R.body_pos(name), lambda m, d, i, b=b: d.xpos[b].copy()
        yield R.body_pos(name, index=(2,)), lambda m, d, i, b=b: d.xpos[b, [2]]
        yield R.body_pos(name, point="com"), lambda m, d, i, b=b: d.xipos[b].copy()
        yield R.body_quat(name), lambda m, d, i, b=b: d.xquat[b].copy()
        for point, objtype in (("origin", _XBODY), ("com", _BODY)):
            for frame in ("world", "local"):
                local = frame == "local"
                yield (
                    R.body_lin_vel(name, frame=frame, point=point),
                    lambda m, d, i, b=b, o=objtype, loc=local: _object_velocity(m, d, o, b, loc)[3:],
                )
                yield (
                    R.body_ang_vel(name, frame=frame, point=point),
                    lambda m, d, i, b=b, o=objtype, loc=local: _object_velocity(m, d, o, b, loc)[:3],
                )
        yield R.projected_gravity(name), lambda m, d, i, b=b: _projected_gravity(m, d, b)
        yield R.subtree_com(name), lambda m, d, i, b=b: d.subtree_com[b].copy()
        yield R.subtree_lin_vel(name), lambda m, d, i, b=b: _subtree_linvel(m, d, b)
        if b:
            yield R.contact_force(name), lambda m, d, i, b=b: _post_constraint_forces(m, d, [b])
    yield R.contact_force(), lambda m, d, i: _post_constraint_forces(m, d, list(range(1, m.nbody)))
    for name in _names(model, "site"):
        yield R.site_pos(name), lambda m, d, i, name=name: d.site(name).xpos.copy()
        site = model.site(name).id
        yield R.site_quat(name), lambda m, d, i, s=site: d.site_xquat[s].copy()
    for name in _names(model, "geom"):
        geom = model.geom(name).id
        yield R.geom_pos(name), lambda m, d, i, g=geom: d.geom_xpos[g].copy()
    yield R.time(), lambda m, d, i: np.array([d.time])
    yield R.data_field("cinert", 1), lambda m, d, i: d.cinert[1:].ravel()
    yield R.data_field("cvel", 1, clip=(-1, 1)), lambda m, d, i: np.clip(d.cvel[1:].ravel(), -1, 1)
    yield R.data_field("qfrc_actuator"), lambda m, d, i: d.qfrc_actuator.copy()
    yield R.data_field("qpos", 0, 2), lambda m, d, i: d.qpos[0:2].copy()
    yield (
        R.data_field("xpos", 1, 3, index=(5, 0), clip=(-0.5, 0.5)),
        lambda m, d, i: np.clip(d.xpos[[2, 1], [2, 0]], -0.5, 0.5),
    )
    yield R.mass_centre(), lambda m, d, i: np.sum(m.body_mass[:, None] * d.xipos, 0) / np.sum(m.body_mass)
    yield (
        R.mass_centre(index=(1, 0)),
        lambda m, d, i: (np.sum(m.body_mass[:, None] * d.xipos, 0) / np.sum(m.body_mass))[[1, 0]],
    )
    yield from _composite_cases(world)


def _compare(world: World) -> dict[str, tuple[str, float]]:
    """kind -> (the worst case's label, its largest relative difference) over every case of the world."""
    worst: dict[str, tuple[str, float]] = {}
    for reading, reference in _cases(world):
        resolved = reading.resolve(world.model)
        arrays = world.arrays(resolved, contacts=True)
        frozen = {name: value.copy() for name, value in arrays.items()}
        value = resolved.compute(arrays)
        expected = np.stack(
            [reference(m, d, i) for i, (m, d) in enumerate(zip(world.models, world.datas, strict=True))]
        )
        assert value.shape == (NUM_ENVS, *resolved.shape) == expected.shape, resolved.label
        assert len(resolved.labels) == int(np.prod(resolved.shape)), resolved.label
        for name, array in arrays.items():  # a new array, the inputs untouched
            assert not np.shares_memory(value, array), (resolved.label, name)
            np.testing.assert_array_equal(array, frozen[name], err_msg=f"{resolved.label} wrote to {name}")
        scale = np.maximum(np.abs(expected), 1e-300)
        difference = float(np.max(np.abs(value - expected) / scale, initial=0.0))
        if not np.array_equal(value, expected):
            difference = max(difference, np.finfo(float).tiny)  # a NaN pattern or a signed zero differs
        if difference >= worst.get(reading.kind, ("", -1.0))[1]:
            worst[reading.kind] = (resolved.label, difference)
    return worst


def test_every_kind_equals_mujoco_bit_for_bit(world: World) -> None:
    """Each kind, on every named object of the model, equals MuJoCo's function on the same MjData, bit for bit."""
    assert any(data.ncon for data in world.datas), f"{world.name}: no contact in any env; the states prove less"
    assert len({data.qpos.tobytes() for data in world.datas}) == NUM_ENVS
    worst = _compare(world)
    assert {kind: found for kind, found in worst.items() if found[1] != 0} == {}


def test_every_kind_is_compared() -> None:
    """The exactness cases cover every kind of READING_KINDS but finite_difference (the env computes that one)."""
    robot = _build_world("robot")
    covered = {reading.kind for reading, _ in _cases(robot)}
    assert covered | {"finite_difference"} == set(R.READING_KINDS)


def test_readings_agree_with_the_sensors_of_the_same_quantity() -> None:
    """The robot's sensors measure what some readings compute: equal (the same formulas in MuJoCo's sensor code)."""
    robot = _build_world("robot")
    pairs = {
        "torso_linvel": R.body_lin_vel("torso"),
        "torso_angvel": R.body_ang_vel("torso"),
        "torso_pos": R.body_pos("torso"),
        "torso_com": R.subtree_com("torso"),
        "torso_subtree_vel": R.subtree_lin_vel("torso"),
        "hip_pos": R.joint_pos("hip"),
        "shoulder_quat": R.joint_pos("shoulder"),
        "hip_motor_frc": R.actuator_force("hip_motor"),
    }
    for name, reading in pairs.items():
        resolved = reading.resolve(robot.model)
        sensed = np.stack([data.sensor(name).data for data in robot.datas])
        np.testing.assert_allclose(resolved.compute(robot.arrays(resolved)), sensed, rtol=1e-12, atol=1e-12)


def _sd(d, name: str) -> np.ndarray:
    return d.sensor(name).data


_ARM = ("arm_root", "arm_shoulder", "arm_elbow", "arm_wrist", "finger", "fingertip", "thumb", "thumbtip")
_QUADRUPED_FORCE_TORQUE = tuple(
    f"{kind}_toe_{leg}"
    for kind in ("force", "torque")
    for leg in ("front_left", "front_right", "back_right", "back_left")
)

#: dm_control's observations (and reward inputs) that need difference, elementwise or norm: model -> (the readings
#: whose values, concatenated, rebuild it; the suite's own numpy expression of it on (model, data))
DM_CONTROL_EXPRESSIONS = {
    "dm_control humanoid": [
        (  # humanoid's extremities
            [
                R.difference(R.body_pos(f"{side}_{limb}"), R.body_pos("torso"), frame="body:torso")
                for side in ("left", "right")
                for limb in ("hand", "foot")
            ],
            lambda m, d: np.hstack(
                [
                    (d.body(f"{side}_{limb}").xpos - d.body("torso").xpos) @ d.body("torso").xmat.reshape(3, 3)
                    for side in ("left", "right")
                    for limb in ("hand", "foot")
                ]
            ),
        ),
        (  # fish's target, in the frame of its mouth geom: here between two of the humanoid's geoms
            [R.difference(R.geom_pos("head"), R.geom_pos("left_hand"), frame="geom:left_hand")],
            lambda m, d: (d.geom("head").xpos - d.geom("left_hand").xpos) @ d.geom("left_hand").xmat.reshape(3, 3),
        ),
    ],
    "dm_control quadruped": [
        (  # quadruped's force_torque
            [R.elementwise(R.sensor(name), "arcsinh") for name in _QUADRUPED_FORCE_TORQUE],
            lambda m, d: np.arcsinh(np.hstack([_sd(d, name) for name in _QUADRUPED_FORCE_TORQUE])),
        ),
    ],
    "dm_control finger": [
        (  # finger's position: the tip's x and z relative to the spinner
            [R.difference(R.sensor("tip"), R.sensor("spinner"), index=(0, 2))],
            lambda m, d: _sd(d, "tip")[[0, 2]] - _sd(d, "spinner")[[0, 2]],
        ),
        (  # finger's dist_to_target: |target_position - tip_position| less the target site's radius
            [R.norm(R.difference(R.sensor("target"), R.sensor("tip"), index=(0, 2)), offset=-0.03)],
            lambda m, d: (
                np.linalg.norm(
                    (_sd(d, "target")[[0, 2]] - _sd(d, "spinner")[[0, 2]])
                    - (_sd(d, "tip")[[0, 2]] - _sd(d, "spinner")[[0, 2]])
                )
                - m.site("target").size[0]
            ),
        ),
    ],
    "dm_control manipulator": [
        (  # manipulator's arm_pos, flattened from (8, 2)
            [R.elementwise(R.joint_pos(*_ARM), "sin_cos")],
            lambda m, d: np.vstack([np.sin(q := np.hstack([d.joint(j).qpos for j in _ARM])), np.cos(q)]).T.ravel(),
        ),
    ],
    "dm_control hopper": [
        (  # hopper's standing height (centres of mass) and touch
            [R.difference(R.body_pos("torso", point="com"), R.body_pos("foot", point="com"), index=(2,))],
            lambda m, d: d.body("torso").xipos[2] - d.body("foot").xipos[2],
        ),
        (
            [R.elementwise(R.sensor("touch_toe"), "log1p"), R.elementwise(R.sensor("touch_heel"), "log1p")],
            lambda m, d: np.log1p(np.hstack([_sd(d, "touch_toe"), _sd(d, "touch_heel")])),
        ),
    ],
    "dm_control swimmer": [
        (  # swimmer's to_target, in the head body's frame
            [R.difference(R.geom_pos("target"), R.geom_pos("nose"), frame="body:head", index=(0, 1))],
            lambda m, d: ((d.geom("target").xpos - d.geom("nose").xpos) @ d.body("head").xmat.reshape(3, 3))[:2],
        ),
    ],
}


def test_composites_equal_dm_controls_numpy_expressions() -> None:
    """difference, elementwise and norm equal dm_control's numpy expressions of the same observations to the last
    bits (numpy's ``@`` and ``linalg.norm`` sum in BLAS's order, the readings in MuJoCo's), on every env."""
    checked = 0
    for name, cases in DM_CONTROL_EXPRESSIONS.items():
        world = _shared_world(name)
        for readings, expression in cases:
            resolved = [reading.resolve(world.model) for reading in readings]
            value = np.hstack([each.compute(world.arrays(each, contacts=True)) for each in resolved])
            expected = np.stack(
                [np.atleast_1d(expression(m, d)) for m, d in zip(world.models, world.datas, strict=True)]
            )
            assert np.abs(expected).max() > 1e-3, (name, resolved[0].label)  # states that test something
            np.testing.assert_allclose(value, expected, rtol=1e-14, atol=1e-15, err_msg=f"{name}: {resolved[0].label}")
            checked += 1
    assert checked == sum(len(cases) for cases in DM_CONTROL_EXPRESSIONS.values())


def test_site_quat_is_the_rotation_of_site_xmat() -> None:
    robot = _build_world("robot")
    resolved = R.site_quat("imu").resolve(robot.model)
    for quat, data in zip(resolved.compute(robot.arrays(resolved)), robot.datas, strict=True):
        matrix = np.zeros(9)
        mujoco.mju_quat2Mat(matrix, quat)
        np.testing.assert_allclose(matrix, data.site("imu").xmat, atol=1e-14)


def test_mass_centre_equals_gymnasiums_mass_center_bit_for_bit() -> None:
    """Gymnasium's humanoid_v5 ``mass_center`` (an einsum over the bodies) gives the same bits, per-env masses."""
    humanoid_v5 = pytest.importorskip("gymnasium.envs.mujoco.humanoid_v5")
    world = _build_world("gymnasium humanoid")
    resolved = R.mass_centre().resolve(world.model)
    value = resolved.compute(world.arrays(resolved))
    expected = np.stack(
        [humanoid_v5.mass_center(model, data) for model, data in zip(world.models, world.datas, strict=True)]
    )
    np.testing.assert_array_equal(value[:, :2], expected)


def test_contact_forces_after_mj_step_differ_from_the_forward_pass_only_under_rk4() -> None:
    """Why Gymnasium's Ant/Humanoid contact forces are not a reading: their ``mj_rnePostConstraint`` after ``mj_step``.

    mj_step runs mj_forward (sensors, and cfrc_ext where a sensor needs it) at the start state, then integrates. RK4
    evaluates three more states with sensors skipped and leaves their contacts and constraint forces in MjData, so an
    mj_rnePostConstraint after the step reads the last RK4 stage, not the step's forward pass; Euler and the implicit
    integrators leave the forward pass's, and the two agree bit for bit.
    """
    for integrator, same in (("RK4", False), ("EULER", True), ("IMPLICITFAST", True)):
        spec = _spec(gymnasium_asset("ant.xml"))
        spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator}")
        with _quiet():
            plain = spec.compile()
        sensed = _with_contact_sensor(spec)
        data, data_sensed = mujoco.MjData(plain), mujoco.MjData(sensed)
        rng = np.random.default_rng(0)
        differences = []
        for _ in range(100):
            data.ctrl[:] = data_sensed.ctrl[:] = rng.uniform(-1, 1, plain.nu)
            mujoco.mj_step(plain, data)
            mujoco.mj_step(sensed, data_sensed)
            mujoco.mj_rnePostConstraint(plain, data)
            differences.append(np.abs(data.cfrc_ext - data_sensed.cfrc_ext).max())
        np.testing.assert_array_equal(data.qpos, data_sensed.qpos)  # the sensor changes no dynamics
        assert (max(differences) == 0) == same, (integrator, max(differences))


# ------------------------------------------------------------------------------------------------ other backends


#: readings whose torch values may differ from numpy's in the last bits (the most ulps): mass_centre's sums over the
#: bodies (torch adds in another order), elementwise's functions (torch's own log1p, arcsinh, sin and cos) and a
#: norm's square root (torch's vectorised sqrt is not always the correctly rounded one)
_TORCH_ULPS = {
    R.mass_centre(): 4,
    R.norm(R.difference(R.sensor("torso_pos"), R.site_pos("foot")), offset=-0.1): 1,
    R.elementwise(R.sensor("torso_touch"), "log1p"): 2,
    R.elementwise(R.joint_vel(), "arcsinh"): 2,
    R.elementwise(R.joint_pos("hip", "knee", "slide"), "sin_cos", index=(3, 0, 4)): 2,
    R.elementwise(R.norm(R.contact_force()), "log1p", clip=(0, 3)): 4,
}


def test_compute_runs_on_torch_tensors_with_the_same_values() -> None:
    """The arithmetic is backend-neutral: torch tensors of the same arrays give the same values, bit for bit but for
    _TORCH_ULPS (a few ulps), and the dtype follows the input."""
    torch = pytest.importorskip("torch")
    robot = _build_world("robot")
    readings = [
        *_TORCH_ULPS,
        R.geom_pos("torso_geom"),
        R.body_pos("thigh", point="com"),
        R.difference(R.body_pos("shin"), R.site_pos("imu"), frame="site:imu"),
        R.difference(R.geom_pos("floor"), R.body_pos("slider", point="com"), frame="geom:torso_geom", index=(0, 2)),
        R.difference(R.sensor("imu_gyro"), R.body_ang_vel("torso", frame="local"), frame="body:shin", clip=(-1, 1)),
        R.difference(R.subtree_lin_vel("torso"), R.last_action(index=(0, 1, 2))),
        R.joint_pos("hip", "knee", relative_to="crouch"),
        R.joint_pos("hip", "slide", relative_to="qpos0", clip=(-0.1, 0.1)),
        R.joint_vel(),
        R.sensor("imu_gyro"),
        R.body_lin_vel("thigh", frame="local", point="com"),
        R.body_ang_vel("shin", frame="local"),
        R.projected_gravity("torso"),
        R.subtree_lin_vel("torso"),
        R.subtree_lin_vel("world"),
        R.contact_force(clip=(-5, 5)),
        R.site_quat("imu"),
        R.last_action(),
        R.time(),
        R.data_field("cinert", 1),
        R.mass_centre(),
    ]
    for reading in readings:
        resolved = reading.resolve(robot.model)
        arrays = robot.arrays(resolved)
        value = resolved.compute(arrays)
        tensors = {name: torch.from_numpy(array.copy()) for name, array in arrays.items()}
        result = resolved.compute(tensors)
        assert isinstance(result, torch.Tensor) and result.dtype == torch.float64, resolved.label
        if reading in _TORCH_ULPS:
            np.testing.assert_array_max_ulp(result.numpy(), value, maxulp=_TORCH_ULPS[reading])
        else:
            np.testing.assert_array_equal(result.numpy(), value, err_msg=resolved.label)
        single = resolved.compute({name: tensor.float() for name, tensor in tensors.items()})
        assert single.dtype == torch.float32, resolved.label


# --------------------------------------------------------------------------------------------------- declarations


def test_readings_are_frozen_picklable_and_compare_by_value() -> None:
    readings = [
        R.joint_pos("hip", relative_to="crouch", clip=(-1, 1)),
        R.body_lin_vel("torso", frame="local", point="com"),
        R.finite_difference(R.body_pos("torso"), dt=0.02),
        R.data_field("cvel", 1),
        R.mass_centre(),
        R.norm(R.difference(R.geom_pos("floor"), R.body_pos("torso", point="com"), frame="site:imu"), offset=-1),
        R.elementwise(R.sensor("torso_touch"), "log1p", clip=(0, 2)),
    ]
    for reading in readings:
        assert pickle.loads(pickle.dumps(reading)) == reading
        assert hash(copy.deepcopy(reading)) == hash(reading)
        with pytest.raises(AttributeError):
            reading.clip = (0, 1)  # type: ignore[misc]
    assert R.joint_pos("hip") != R.joint_pos("knee")
    assert R.body_lin_vel("torso") != R.body_ang_vel("torso")
    assert R.body_pos("torso") != R.body_pos("torso", point="com")
    assert R.difference(R.time(), R.time()) != R.difference(R.time(), R.time(), index=(0,))
    robot = _build_world("robot")
    for reading in (R.subtree_lin_vel("torso", clip=(-1, 1)), readings[-2], readings[-1]):
        resolved = reading.resolve(robot.model)
        restored = pickle.loads(pickle.dumps(resolved))
        arrays = robot.arrays(resolved)
        np.testing.assert_array_equal(restored.compute(arrays), resolved.compute(arrays))


def test_labels_and_finite_difference_resolution() -> None:
    model = load_model(ROBOT)
    assert R.body_lin_vel("torso", frame="local", clip=(-1, 2.5)).resolve(model).label == (
        "body_lin_vel(torso, frame=local, clip=(-1, 2.5))"
    )
    resolved = R.joint_pos("root", "shoulder", "hip").resolve(model)
    assert resolved.labels == (
        *("root.x", "root.y", "root.z", "root.qw", "root.qx", "root.qy", "root.qz"),
        *("shoulder.qw", "shoulder.qx", "shoulder.qy", "shoulder.qz"),
        "hip",
    )
    inner = R.body_pos("torso")
    difference = R.finite_difference(inner, dt=0.05).resolve(model)
    assert difference.label == "finite_difference(body_pos(torso), dt=0.05)"
    assert difference.difference_of == dataclasses.replace(
        inner.resolve(model), compute=difference.difference_of.compute
    )
    assert (difference.shape, difference.fields, difference.dt) == ((3,), ("xpos",), 0.05)
    with pytest.raises(RuntimeError, match="keeps the reading's previous value"):
        difference.compute({"xpos": np.zeros((2, model.nbody, 3))})


def test_composites_unite_what_their_inputs_read() -> None:
    """A composite resolves its inputs and reads what they read (once each, in order), its frame's rotation too; it
    needs contact forces or the last action when an input does; its labels name its entries."""
    model = load_model(ROBOT)
    resolved = R.difference(R.subtree_lin_vel("torso"), R.mass_centre(), frame="site:imu").resolve(model)
    assert resolved.fields == ("cvel", "xipos", "subtree_com", "site_xmat")
    assert resolved.model_fields == ("body_mass", "body_subtreemass")
    assert (resolved.shape, resolved.contact_forces, resolved.action, resolved.difference_of) == (
        (3,),
        False,
        False,
        None,
    )
    forces = R.norm(R.elementwise(R.contact_force("shin", "thigh"), "arcsinh")).resolve(model)
    assert (forces.fields, forces.shape, forces.contact_forces, forces.action) == (("cfrc_ext",), (1,), True, False)
    action = R.difference(R.last_action(), R.actuator_ctrl(), clip=(-1, 1)).resolve(model)
    assert (action.fields, action.action, action.contact_forces) == (("ctrl",), True, False)
    assert action.labels == ("hip_motor - hip_motor", "knee_servo - knee_servo", "slide_motor - slide_motor")
    relative = R.difference(R.joint_pos("hip", relative_to="qpos0"), R.sensor("hip_pos")).resolve(model)
    assert (relative.fields, relative.model_fields, relative.labels) == (
        ("qpos", "sensordata"),
        ("qpos0",),
        ("hip - hip_pos",),
    )
    framed = R.difference(R.body_pos("shin"), R.body_pos("torso"), frame="body:torso", index=(2,), clip=(-1, 1))
    resolved = framed.resolve(model)
    assert resolved.label == "difference(body_pos(shin), body_pos(torso), frame=body:torso, index=(2,), clip=(-1, 1))"
    assert (resolved.shape, resolved.fields) == ((1,), ("xpos", "xmat"))
    assert resolved.labels == ("difference(body_pos(shin), body_pos(torso), frame=body:torso).z",)
    geom = R.difference(R.geom_pos("torso_geom"), R.body_pos("torso", point="com"), frame="geom:torso_geom")
    assert geom.resolve(model).fields == ("geom_xpos", "xipos", "geom_xmat")
    waves = R.elementwise(R.joint_pos("hip", "knee"), "sin_cos").resolve(model)
    assert (waves.label, waves.shape) == ("elementwise(joint_pos(hip, knee), sin_cos)", (4,))
    assert waves.labels == ("sin(hip)", "cos(hip)", "sin(knee)", "cos(knee)")
    assert R.elementwise(R.sensor("torso_touch"), "log1p").resolve(model).labels == ("log1p(torso_touch)",)
    assert R.elementwise(R.joint_vel("hip"), "arcsinh").resolve(model).labels == ("arcsinh(hip)",)
    distance = R.norm(R.site_pos("foot", index=(0, 2)), offset=-0.07).resolve(model)
    assert (distance.label, distance.labels) == (
        "norm(site_pos(foot, index=(0, 2)), offset=-0.07)",
        ("norm(site_pos(foot, index=(0, 2)), offset=-0.07)",),
    )
    centre = R.body_pos("torso", point="com").resolve(model)
    assert (centre.label, centre.fields, centre.labels) == (
        "body_pos(torso, point=com)",
        ("xipos",),
        ("torso.x", "torso.y", "torso.z"),
    )
    assert R.geom_pos("floor", index=(2,)).resolve(model).labels == ("floor.z",)


def test_a_finite_difference_of_a_composite_differences_its_value() -> None:
    """finite_difference of a composite reading names it (the env keeps its previous value) with all it reads."""
    robot = _build_world("robot")
    inner = R.norm(R.difference(R.body_pos("shin"), R.site_pos("imu"), frame="body:torso"), offset=-0.5)
    resolved = R.finite_difference(inner, dt=0.02).resolve(robot.model)
    assert (
        resolved.label
        == "finite_difference(norm(difference(body_pos(shin), site_pos(imu), frame=body:torso), offset=-0.5), dt=0.02)"
    )
    assert (resolved.shape, resolved.fields, resolved.dt) == ((1,), ("xpos", "site_xpos", "xmat"), 0.02)
    assert resolved.labels == ("d(norm(difference(body_pos(shin), site_pos(imu), frame=body:torso), offset=-0.5))",)
    shin, torso, imu = robot.model.body("shin").id, robot.model.body("torso").id, robot.model.site("imu").id
    expected = [[_norm3(_in_frame(d.xmat[torso], d.xpos[shin] - d.site_xpos[imu])) - 0.5] for d in robot.datas]
    value = resolved.difference_of.compute(robot.arrays(resolved.difference_of))
    np.testing.assert_array_equal(value, np.array(expected))


# ------------------------------------------------------------------------------------------------------ bad input


def test_bad_input_is_refused_clearly() -> None:
    model = load_model(ROBOT)
    cases = [
        # unknown names: the closest names of the kind
        (
            ValueError,
            r"joint_pos joints: the model has no joint 'kne'; did you mean 'knee'",
            R.joint_pos("kne").resolve,
        ),
        (
            ValueError,
            r"body_lin_vel body: the model has no body 'torsoo'; did you mean 'torso'",
            R.body_lin_vel("torsoo").resolve,
        ),
        (ValueError, r"actuator_force actuators: .* did you mean 'hip_motor'", R.actuator_force("hip_moter").resolve),
        (
            ValueError,
            r"sensor name: the model has no sensor 'imu_gyr'; did you mean 'imu_gyro'",
            R.sensor("imu_gyr").resolve,
        ),
        (ValueError, r"site_pos site: the model has no site 'fot'; did you mean 'foot'", R.site_pos("fot").resolve),
        (ValueError, r"contact_force bodies: .* did you mean 'shin'", R.contact_force("shinn").resolve),
        (
            ValueError,
            r"relative_to: the model has no keyframe 'crouh'; did you mean 'crouch'",
            R.joint_pos("hip", relative_to="crouh").resolve,
        ),
        # what the model cannot give
        (ValueError, r"joint 'root' is a free joint; only hinge and slide", R.joint_pos(relative_to="qpos0").resolve),
        (ValueError, r"joint 'shoulder' is a ball joint", R.joint_pos("shoulder", relative_to="crouch").resolve),
        (
            ValueError,
            r"data_field\(time\): the field holds float64 of shape \(\) per env",
            R.data_field("time").resolve,
        ),
        (ValueError, r"data_field\(cinert\) start must be below its 6 rows, got 6", R.data_field("cinert", 6).resolve),
        (
            ValueError,
            r"data_field\(cinert\) stop must be at most its 6 rows, got 7",
            R.data_field("cinert", 1, 7).resolve,
        ),
        (
            ValueError,
            r"body_pos\(torso, index=\(3,\)\): index must be positions in \[0, 3\) of its 3 elements, got \(3,\)",
            R.body_pos("torso", index=(3,)).resolve,
        ),
        (
            ValueError,
            r"geom_pos geom: the model has no geom 'torso_gem'; did you mean 'torso_geom'",
            R.geom_pos("torso_gem").resolve,
        ),
        # composites: their inputs' names, their shapes, their frames
        (
            ValueError,
            r"body_pos body: the model has no body 'shn'; did you mean 'shin'",
            R.difference(R.body_pos("torso"), R.body_pos("shn")).resolve,
        ),
        (
            ValueError,
            r"sensor name: the model has no sensor 'touch'",
            R.norm(R.elementwise(R.sensor("touch"), "log1p")).resolve,
        ),
        (
            ValueError,
            r"difference\(body_pos\(torso\), body_quat\(torso\)\): a and b must have the same shape, got \(3,\) "
            r"\(body_pos\(torso\)\) and \(4,\) \(body_quat\(torso\)\)",
            R.difference(R.body_pos("torso"), R.body_quat("torso")).resolve,
        ),
        (
            ValueError,
            r"frame=body:torso expresses 3-vectors in its axes, so a and b must have shape \(3,\), got \(2,\) "
            r"\(joint_pos\(hip, knee\), joint_vel\(hip, knee\)\)",
            R.difference(R.joint_pos("hip", "knee"), R.joint_vel("hip", "knee"), frame="body:torso").resolve,
        ),
        (
            ValueError,
            r"difference frame: the model has no site 'im'; did you mean 'imu'",
            R.difference(R.body_pos("torso"), R.site_pos("imu"), frame="site:im").resolve,
        ),
        (
            ValueError,
            r"difference frame: the model has no geom 'torso'; did you mean 'torso_geom'",
            R.difference(R.body_pos("torso"), R.site_pos("imu"), frame="geom:torso").resolve,
        ),
        (
            ValueError,
            r"norm\(time\(\), index=\(1,\)\): index must be positions in \[0, 1\) of its 1 elements, got \(1,\)",
            R.norm(R.time(), index=(1,)).resolve,
        ),
        (
            ValueError,
            r"index must be positions in \[0, 6\) of its 6 elements, got \(6,\)",
            R.elementwise(R.body_pos("torso"), "sin_cos", index=(6,)).resolve,
        ),
    ]
    for error, match, resolve in cases:
        with pytest.raises(error, match=match):
            resolve(model)
    no_sensor = load_model('<mujoco><worldbody><body name="b"><joint/><geom size=".1"/></body></worldbody></mujoco>')
    with pytest.raises(ValueError, match=r"sensor name: the model has no named sensor, so none called 'gyro'"):
        R.sensor("gyro").resolve(no_sensor)
    with pytest.raises(ValueError, match=r"last_action: the model has no actuator"):
        R.last_action().resolve(no_sensor)
    body = '<worldbody><body name="b"><freejoint/><geom size=".1"/></body></worldbody>'
    for option in ('gravity="0 0 0"', 'gravity="0 0 -9.81"><flag gravity="disable"/></option><option'):
        weightless = load_model(f"<mujoco><option {option}/>{body}</mujoco>")
        with pytest.raises(ValueError, match=r"projected_gravity\(b\): the model (has zero gravity|disables gravity)"):
            R.projected_gravity("b").resolve(weightless)


def test_bad_arguments_are_refused_when_declared() -> None:
    cases = [
        (TypeError, r"joint_pos joints must be the name of a joint \(a string\), got 3", lambda: R.joint_pos(3)),
        (
            ValueError,
            r"joint_pos joints names each joint once, got 'hip' more than once",
            lambda: R.joint_pos("hip", "hip"),
        ),
        (TypeError, r"joint_vel joints must be a sequence of joint names, got 'hip'", lambda: R.JointVel(joints="hip")),
        (ValueError, r"sensor name must be the name of a sensor, got the empty string", lambda: R.sensor("")),
        (TypeError, r"body_pos body must be the name of a body \(a string\), got None", lambda: R.body_pos(None)),
        (
            ValueError,
            r"body_lin_vel frame must be one of \['world', 'local'\], got 'body'",
            lambda: R.body_lin_vel("t", frame="body"),
        ),
        (
            ValueError,
            r"body_ang_vel point must be one of \['origin', 'com'\], got 'centre'",
            lambda: R.body_ang_vel("t", point="centre"),
        ),
        (ValueError, r"clip must be \(low, high\) with low <= high, got \(2, 1\)", lambda: R.time(clip=(2, 1))),
        (
            ValueError,
            r"clip must be finite numbers \(low, high\), got \(nan, 1\)",
            lambda: R.time(clip=(float("nan"), 1)),
        ),
        (
            ValueError,
            r"clip must be finite numbers \(low, high\), got \(0, inf\)",
            lambda: R.time(clip=(0, float("inf"))),
        ),
        (TypeError, r"clip must be None or a pair \(low, high\) of numbers, got 1.0", lambda: R.time(clip=1.0)),
        (
            TypeError,
            r"clip must be None or a pair \(low, high\) of numbers, got \(0, 1, 2\)",
            lambda: R.time(clip=(0, 1, 2)),
        ),
        (TypeError, r"clip must be a pair \(low, high\) of numbers, got \('a', 'b'\)", lambda: R.time(clip=("a", "b"))),
        (
            TypeError,
            r"finite_difference reading must be a reading .*, got 'torso'",
            lambda: R.finite_difference("torso"),
        ),
        (
            ValueError,
            r"must not be a finite difference itself",
            lambda: R.finite_difference(R.finite_difference(R.time())),
        ),
        (
            ValueError,
            r"finite_difference dt must be a finite number of seconds > 0, got 0",
            lambda: R.finite_difference(R.time(), dt=0),
        ),
        (
            TypeError,
            r"finite_difference dt must be None or a number of seconds, got '0.1'",
            lambda: R.finite_difference(R.time(), dt="0.1"),
        ),
        (
            ValueError,
            r"finite_difference takes no index or clip",
            lambda: R.FiniteDifference(reading=R.time(), clip=(0, 1)),
        ),
        (
            ValueError,
            r"finite_difference takes no index or clip",
            lambda: R.FiniteDifference(reading=R.time(), index=(0,)),
        ),
        (
            TypeError,
            r"index must be None, an int or a sequence of element positions \(ints\), got 2.0",
            lambda: R.body_pos("t", index=2.0),
        ),
        (
            TypeError,
            r"index must be a sequence of element positions \(ints\), got \(0.5,\)",
            lambda: R.time(index=(0.5,)),
        ),
        (ValueError, r"index must select at least one element, got an empty sequence", lambda: R.time(index=())),
        (
            TypeError,
            r"data_field stop must be None or an int \(the row after the last\), got '2'",
            lambda: R.data_field("cvel", 1, "2"),
        ),
        (ValueError, r"data_field stop must be above start 2, got 2", lambda: R.data_field("cvel", 2, 2)),
        (
            ValueError,
            r"data_field name must be an MjData field the batch binds; did you mean 'cinert'",
            lambda: R.data_field("cinertia"),
        ),
        (TypeError, r"data_field start must be an int \(the first row\), got 1.5", lambda: R.data_field("cvel", 1.5)),
        (ValueError, r"data_field start must be >= 0 \(the first row\), got -1", lambda: R.data_field("cvel", -1)),
        (
            TypeError,
            r"resolve takes a compiled mujoco.MjModel .*, got str",
            lambda: R.mass_centre().resolve("robot.xml"),
        ),
        (
            ValueError,
            r"body_pos point must be one of \['origin', 'com'\], got 'centre'",
            lambda: R.body_pos("t", point="centre"),
        ),
        (TypeError, r"geom_pos geom must be the name of a geom \(a string\), got None", lambda: R.geom_pos(None)),
        # composites: their inputs, frames, functions and offsets
        (
            TypeError,
            r"difference a must be a reading \(e.g. body_pos\('torso'\)\), got 'torso'",
            lambda: R.difference("torso", R.body_pos("torso")),
        ),
        (TypeError, r"difference b must be a reading .*, got None", lambda: R.Difference(a=R.time())),
        (
            ValueError,
            r"difference a must not be a finite difference .*, got finite_difference\(time\(\)\)",
            lambda: R.difference(R.finite_difference(R.time()), R.time()),
        ),
        (
            ValueError,
            r"norm reading must not be a finite difference .*finite_difference\(\.\.\.\) of the composite",
            lambda: R.norm(R.finite_difference(R.body_pos("t"))),
        ),
        (
            ValueError,
            r"difference frame must be None or 'body:<name>', 'geom:<name>' or 'site:<name>' .*, got 'torso'",
            lambda: R.difference(R.time(), R.time(), frame="torso"),
        ),
        (
            ValueError,
            r"difference frame must be None or .*, got 'body:'",
            lambda: R.difference(R.time(), R.time(), frame="body:"),
        ),
        (
            ValueError,
            r"the kind 'bdy' of 'bdy:torso' is none of \['body', 'geom', 'site'\]; did you mean 'body'",
            lambda: R.difference(R.time(), R.time(), frame="bdy:torso"),
        ),
        (
            ValueError,
            r"difference frame must be .*: the kind 'camera' of 'camera:eye' is none of",
            lambda: R.difference(R.time(), R.time(), frame="camera:eye"),
        ),
        (
            TypeError,
            r"difference frame must be None or a string .*, got 3",
            lambda: R.difference(R.time(), R.time(), frame=3),
        ),
        (
            ValueError,
            r"elementwise function must be one of \['log1p', 'arcsinh', 'sin_cos'\], got 'log1'; did you mean 'log1p'",
            lambda: R.elementwise(R.time(), "log1"),
        ),
        (ValueError, r"elementwise function must be one of .*, got 'exp'", lambda: R.elementwise(R.time(), "exp")),
        (
            TypeError,
            r"elementwise function must be the name of a function \(a string\), got <ufunc 'log1p'>",
            lambda: R.elementwise(R.time(), np.log1p),
        ),
        (TypeError, r"elementwise reading must be a reading .*, got 'torso'", lambda: R.elementwise("torso", "log1p")),
        (TypeError, r"norm reading must be a reading .*, got \[\]", lambda: R.norm([])),
        (TypeError, r"norm offset must be a number, got '0.1'", lambda: R.norm(R.time(), offset="0.1")),
        (TypeError, r"norm offset must be a number, got True", lambda: R.norm(R.time(), offset=True)),
        (ValueError, r"norm offset must be a finite number, got nan", lambda: R.norm(R.time(), offset=float("nan"))),
        (
            ValueError,
            r"clip must be \(low, high\) with low <= high, got \(1, 0\)",
            lambda: R.norm(R.time(), clip=(1, 0)),
        ),
    ]
    for error, match, declare in cases:
        with pytest.raises(error, match=match):
            declare()
