"""The MJCF models torchtasks ships (torchtasks.envs.models) behave as their headers say, under plain MuJoCo.

Each shipped model compiles and names what its header lists. The quadruped stands still at its ``"home"`` keyframe
with ``ctrl`` held at the keyframe's (feet on the ground and no other contact, the torso's height, position and tilt
in a narrow band over 5 s, the IMU reading gravity), and a fall is a contact a task can read: with its servos
targeting zero, with actuation switched off, or with random targets, a body other than a foot touches the floor.
The arm is usable: a Jacobian-transpose PD controller on its motors brings the fingertip onto targets it can reach.
Expected values are the models' physical facts (the floor is at z = 0, gravity is 9.81 m/s², the keyframe's
height puts the feet on the floor), not outputs of the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from torchtasks.envs.models import MODEL_NAMES, model_path  # noqa: E402

pytestmark = pytest.mark.mujoco

LEGS = ("FL", "FR", "RL", "RR")
#: the quadruped's control step: 4 substeps of 5 ms
SUBSTEPS = 4


def load(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(model_path(name)))


def at_keyframe(model: mujoco.MjModel, key: str = "home") -> mujoco.MjData:
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key(key).id)
    mujoco.mj_forward(model, data)
    return data


def floor_contacts(model: mujoco.MjModel, data: mujoco.MjData) -> set[str]:
    """The names of the geoms in contact with the floor."""
    floor = model.geom("floor").id
    touching = set()
    for contact in data.contact[: data.ncon]:
        if floor in (contact.geom1, contact.geom2):
            other = contact.geom2 if contact.geom1 == floor else contact.geom1
            touching.add(model.geom(other).name)
    return touching


@pytest.fixture(scope="module")
def quadruped() -> mujoco.MjModel:
    return load("quadruped")


def test_every_shipped_model_compiles_and_has_a_home_keyframe():
    assert set(MODEL_NAMES) == {"arm", "quadruped"}
    for name in MODEL_NAMES:
        model = load(name)
        assert model.nu > 0, name
        data = at_keyframe(model)
        assert np.all(np.isfinite(data.qacc)), name


def test_model_path_refuses_what_is_not_shipped():
    with pytest.raises(ValueError, match=r"no shipped model 'humanoid'.*'arm', 'quadruped'"):
        model_path("humanoid")
    with pytest.raises(ValueError, match=r"did you mean 'arm'"):
        model_path("arm.xml")
    with pytest.raises(TypeError, match="name must be a string"):
        model_path(model_path("arm"))  # type: ignore[arg-type]


def test_quadruped_names_ranges_and_scale(quadruped):
    model = quadruped
    assert 10.0 <= model.body_subtreemass[model.body("torso").id] <= 15.0
    assert model.opt.timestep == 0.005
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and model.nu == 12 and model.nq == 19
    home = model.key("home")
    for leg in LEGS:
        model.site(f"{leg}_foot_site")
        model.sensor(f"{leg}_touch")
        for link in ("hip", "thigh", "calf"):
            model.body(f"{leg}_{link}")
            joint = model.joint(f"{leg}_{link}_joint")
            actuator = model.actuator(f"{leg}_{link}")
            # a position servo on its joint, targets over the joint's range, a torque limit
            assert actuator.trnid[0] == joint.id
            assert actuator.biastype[0] == mujoco.mjtBias.mjBIAS_AFFINE and actuator.gainprm[0] > 0
            np.testing.assert_array_equal(actuator.ctrlrange, joint.range)
            assert actuator.forcelimited[0] and actuator.forcerange[1] > 0
            # the keyframe's ctrl is its joint angle, inside the range
            angle = home.qpos[joint.qposadr[0]]
            assert home.ctrl[actuator.id] == angle
            assert joint.range[0] < angle < joint.range[1]
    for sensor in ("imu_gyro", "imu_acc", "imu_vel", "torso_quat"):
        model.sensor(sensor)
    model.site("imu")


def test_quadruped_home_puts_the_feet_on_the_floor(quadruped):
    model = quadruped
    data = at_keyframe(model)
    floor_z = 0.0
    for leg in LEGS:
        foot = model.geom(f"{leg}_foot")
        bottom = data.geom_xpos[foot.id, 2] - foot.size[0]
        assert abs(bottom - floor_z) < 1e-3, (leg, bottom)
    # nothing but the feet near the floor: the lowest other geom is well above it
    for geom in range(model.ngeom):
        name = model.geom(geom).name
        if name != "floor" and not name.endswith("_foot"):
            assert data.geom_xpos[geom, 2] > 0.05, name


def test_quadruped_stands_still_at_home(quadruped):
    model = quadruped
    data = at_keyframe(model)
    ctrl = model.key("home").ctrl.copy()
    start_height = data.qpos[2]
    steps = round(5.0 / model.opt.timestep)
    settled = round(2.0 / model.opt.timestep)
    positions = np.empty((steps, 3))
    tilts = np.empty(steps)
    for step in range(steps):
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data)
        positions[step] = data.qpos[:3]
        tilts[step] = np.degrees(np.arccos(np.clip(data.xmat[model.body("torso").id, 8], -1.0, 1.0)))
        if step >= settled:
            assert floor_contacts(model, data) == {f"{leg}_foot" for leg in LEGS}, step
    # it sinks into its servos' sag under its weight (about 9 mm), never bounces above the keyframe, never falls
    assert np.all(positions[:, 2] <= start_height + 1e-3)
    assert np.all(positions[:, 2] >= start_height - 0.015)
    # then it stays still: sub-millimetre over the last 3 s, upright
    late = positions[settled:]
    assert np.ptp(late[:, 2]) < 1e-3
    assert np.abs(late[:, :2] - late[0, :2]).max() < 1e-3
    assert np.abs(positions[:, :2]).max() < 0.02
    # level: its centre of mass is over its feet (measured 0.17 degrees; 0.6 with the torso's box centred on the hips)
    assert tilts.max() < 1.0 and tilts[settled:].max() < 0.3
    # the four feet carry its weight, the IMU at rest reads gravity upwards and no rotation
    touch = np.array([data.sensor(f"{leg}_touch").data[0] for leg in LEGS])
    weight = model.body_subtreemass[model.body("torso").id] * 9.81
    assert np.all(touch > 0.15 * weight)
    np.testing.assert_allclose(touch.sum(), weight, rtol=0.02)
    np.testing.assert_allclose(data.sensor("imu_acc").data, [0.0, 0.0, 9.81], atol=0.2)
    np.testing.assert_allclose(data.sensor("imu_gyro").data, 0.0, atol=1e-2)
    np.testing.assert_allclose(data.sensor("imu_vel").data, 0.0, atol=1e-2)
    np.testing.assert_allclose(np.abs(data.sensor("torso_quat").data[0]), 1.0, atol=1e-3)


def first_fall(model: mujoco.MjModel, controls, seconds: float) -> tuple[float, set[str]] | None:
    """The time and the geoms when a geom other than a foot first touches the floor, from "home"; None if never.

    ``controls(step)`` gives the ctrl held over control step ``step`` (4 substeps).
    """
    data = at_keyframe(model)
    for substep in range(round(seconds / model.opt.timestep)):
        if substep % SUBSTEPS == 0:
            data.ctrl[:] = controls(substep // SUBSTEPS)
        mujoco.mj_step(model, data)
        fallen = {name for name in floor_contacts(model, data) if not name.endswith("_foot")}
        if fallen:
            return data.time, fallen
    return None


def test_quadruped_falls_onto_its_torso_when_its_servos_target_zero(quadruped):
    # it tips over backwards: the torso itself reaches the floor (a torso contact is a fall a task can read)
    data = at_keyframe(quadruped)
    touched = False
    for _ in range(round(3.0 / quadruped.opt.timestep)):
        data.ctrl[:] = 0.0
        mujoco.mj_step(quadruped, data)
        touched |= "torso" in floor_contacts(quadruped, data)
    assert touched
    assert data.qpos[2] < 0.15


def test_quadruped_collapses_without_actuation():
    model = load("quadruped")
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
    fall = first_fall(model, lambda step: model.key("home").ctrl, seconds=2.0)
    assert fall is not None
    time, fallen = fall
    assert time < 1.0 and fallen <= {f"{leg}_{link}" for leg in LEGS for link in ("hip", "thigh", "calf")} | {"torso"}


def test_quadruped_falls_under_random_targets(quadruped):
    low, high = quadruped.actuator_ctrlrange.T
    for seed in range(3):
        rng = np.random.default_rng(seed)
        targets = rng.uniform(low, high, size=(1000, quadruped.nu))
        fall = first_fall(quadruped, lambda step, targets=targets: targets[step], seconds=4.0)
        assert fall is not None, seed


def test_arm_fingertip_reaches_targets_with_a_jacobian_pd_controller():
    model = load("arm")
    fingertip, target = model.site("fingertip").id, model.site("target").id
    gear = model.actuator_gear[:, 0]
    arm_dofs = [model.joint(name).dofadr[0] for name in ("shoulder", "elbow")]
    assert model.nu == 2 and list(model.actuator_trnid[:, 0]) == [model.joint("shoulder").id, model.joint("elbow").id]
    jacobian = np.zeros((3, model.nv))
    rng = np.random.default_rng(0)
    # targets in the reachable ring (0.24 m arm), all around the base
    for _ in range(4):
        radius, angle = rng.uniform(0.08, 0.22), rng.uniform(-np.pi, np.pi)
        goal = radius * np.array([np.cos(angle), np.sin(angle)])
        data = at_keyframe(model)
        data.qpos[model.joint("target_x").qposadr[0]], data.qpos[model.joint("target_y").qposadr[0]] = goal
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(data.site_xpos[target, :2], goal, atol=1e-12)
        for _ in range(round(2.0 / model.opt.timestep)):
            mujoco.mj_jacSite(model, data, jacobian, None, fingertip)
            planar = jacobian[:2][:, arm_dofs]
            error = data.site_xpos[target, :2] - data.site_xpos[fingertip, :2]
            torque = planar.T @ (10.0 * error - 0.5 * planar @ data.qvel[arm_dofs])
            data.ctrl[:] = np.clip(torque / gear, -1.0, 1.0)
            mujoco.mj_step(model, data)
        # the target stayed where it was put, and the fingertip is on it, at rest
        np.testing.assert_allclose(data.site_xpos[target, :2], goal, atol=1e-9)
        assert np.linalg.norm(data.site_xpos[fingertip, :2] - goal) < 5e-3
        assert np.abs(data.qvel[arm_dofs]).max() < 0.05
