"""BatchedMujocoEnv's actuator gains as domain fields: ``actuator_kp``, ``actuator_kv``, ``actuator_gain`` (+ scales).

The reference of every trajectory is one ``MjData`` per env on its own copy of the nominal ``MjModel`` whose actuator
parameters are set by hand from MuJoCo's definition of each actuator (a ``<position>`` servo: ``gainprm[0] = kp``,
``biasprm[1] = -kp``, ``biasprm[2] = -kv``; a ``<velocity>`` servo: ``gainprm[0] = kv``, ``biasprm[2] = -kv``; a
``<motor>``: ``gainprm[0]`` its gain), each value its own (nominal until set) times its kind's scale, and stepped with
``mj_step``. The roles of the actuators are written here from the MJCF, not asked of the code under test.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")

from tensordict import TensorDict  # noqa: E402
from torchrl.envs import TransformedEnv  # noqa: E402

from torchtasks.domain import UniformDomainParam  # noqa: E402
from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs import readings as R  # noqa: E402
from torchtasks.envs.models import model_path  # noqa: E402
from torchtasks.envs.mujoco_declaration import Resets  # noqa: E402
from torchtasks.transforms import DomainRandomization  # noqa: E402

pytestmark = pytest.mark.mujoco

NUM_ENVS = 4
STEPS = 20
FRAME_SKIP = 2
#: the step before which envs MID_MASK get new values mid-episode; env 3 is nominal until then
MID_EPISODE = 10
FIRST_MASK = [True, True, True, False]
MID_MASK = [False, True, False, True]

#: an arm of four joints, each driven by another kind of actuator
ARM = """
<mujoco>
  <option timestep="0.002" integrator="implicitfast"/>
  <worldbody>
    <body name="upper"><joint name="shoulder" axis="0 1 0" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04" mass="1"/>
      <body name="fore" pos="0.3 0 0"><joint name="elbow" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.5"/>
        <body name="hand" pos="0.3 0 0"><joint name="wrist" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.02" mass="0.2"/>
          <body name="tip" pos="0.1 0 0"><joint name="slider" type="slide" axis="1 0 0" range="-0.05 0.05"/>
            <geom type="box" size="0.02 0.01 0.01" mass="0.05"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="shoulder" joint="shoulder" kp="20" ctrlrange="-1 1"/>
    <position name="elbow" joint="elbow" kp="10" kv="1" ctrlrange="-1 1"/>
    <velocity name="wrist" joint="wrist" kv="0.2" ctrlrange="-2 2"/>
    <motor name="slider" joint="slider" gear="3" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""
#: what each of ARM's actuators is, from its MJCF element
ARM_ROLES = {"shoulder": "position", "elbow": "position", "wrist": "velocity", "slider": "motor"}
#: the shipped quadruped: 12 <position> servos, kp 100, no kv
QUADRUPED_ROLES = dict.fromkeys(
    [f"{leg}_{part}" for leg in ("FL", "FR", "RL", "RR") for part in ("hip", "thigh", "calf")], "position"
)


def reference_model(nominal: mujoco.MjModel, roles: dict[str, str], values: dict[str, float]) -> mujoco.MjModel:
    """A copy of ``nominal`` with one env's gains (``values``: field name -> value) set by MuJoCo's definition."""
    model = copy.copy(nominal)

    def value(kind: str, actuator: str, nominal_value: float) -> float:
        return values.get(f"{kind}:{actuator}", nominal_value) * values.get(f"{kind}_scale", 1.0)

    for actuator, role in roles.items():
        i = nominal.actuator(actuator).id
        gain, bias = nominal.actuator_gainprm[i], nominal.actuator_biasprm[i]
        if role == "position":  # force = kp * ctrl - kp * length - kv * velocity
            kp, kv = value("actuator_kp", actuator, gain[0]), value("actuator_kv", actuator, -bias[2])
            model.actuator_gainprm[i, 0], model.actuator_biasprm[i, 1], model.actuator_biasprm[i, 2] = kp, -kp, -kv
        elif role == "velocity":  # force = kv * ctrl - kv * velocity
            kv = value("actuator_kv", actuator, gain[0])
            model.actuator_gainprm[i, 0], model.actuator_biasprm[i, 2] = kv, -kv
        else:  # a motor: force = gain * ctrl
            model.actuator_gainprm[i, 0] = value("actuator_gain", actuator, gain[0])
    return model


def _draw(names: list[str], nominal: dict[str, float], rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Per-env values: a factor in [0.5, 1.5] of the nominal value (a kv of 0: a value in [0.5, 3])."""
    out = {}
    for name in names:
        base = nominal.get(name, 1.0)
        value = rng.uniform(0.5, 3.0, NUM_ENVS) if base == 0.0 else base * rng.uniform(0.5, 1.5, NUM_ENVS)
        out[name] = torch.from_numpy(value)
    return out


CASES = {
    # per-object kp and kv (from 0: a damping added) on three servos, then the scales composing with them
    "quadruped": (
        lambda: str(model_path("quadruped")),
        QUADRUPED_ROLES,
        Resets(keyframe="home"),
        ["actuator_kp:FL_thigh", "actuator_kp:RR_calf", "actuator_kv:FL_thigh", "actuator_kv:FR_hip"],
        ["actuator_kp_scale", "actuator_kv_scale"],
    ),
    # a position servo with and without kv, a velocity servo (its gain and bias together), a motor
    "arm": (
        lambda: ARM,
        ARM_ROLES,
        None,
        ["actuator_kp:shoulder", "actuator_kp:elbow", "actuator_kv:elbow", "actuator_kv:wrist", "actuator_gain:slider"],
        ["actuator_kp_scale", "actuator_kv_scale", "actuator_gain_scale"],
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_per_env_gains_step_as_hand_set_models_bit_for_bit(case: str) -> None:
    source, roles, resets, first_names, mid_names = CASES[case]
    readings = {"qpos": R.joint_pos(), "qvel": R.joint_vel(), "force": R.actuator_force()}
    env = BatchedMujocoEnv(source(), NUM_ENVS, observation=readings, resets=resets, frame_skip=FRAME_SKIP,
                           stage="step", seed=0, num_threads=2)  # fmt: skip
    nominal = env.model
    nominal_values = {
        f"{kind}:{actuator}": value
        for actuator, role in roles.items()
        for kind, value in (
            ("actuator_kp", nominal.actuator(actuator).gainprm[0]),
            ("actuator_kv", -nominal.actuator(actuator).biasprm[2] + 0.0),
            ("actuator_gain", nominal.actuator(actuator).gainprm[0]),
        )
    }
    rng = np.random.default_rng(1)
    per_env: list[dict[str, float]] = [{} for _ in range(NUM_ENVS)]

    def write(values: dict[str, torch.Tensor], mask: list[bool]) -> None:
        env.set_domain(values, torch.tensor(mask))
        for i in np.flatnonzero(mask).tolist():
            per_env[i].update({name: float(value[i]) for name, value in values.items()})

    write(_draw(first_names, nominal_values, rng), FIRST_MASK)  # before the first reset, env 3 left nominal
    out = env.reset()
    models = [reference_model(nominal, roles, values) for values in per_env]
    datas = [mujoco.MjData(model) for model in models]
    for model, data in zip(models, datas, strict=True):
        if resets is None:
            mujoco.mj_resetData(model, data)
        else:
            mujoco.mj_resetDataKeyframe(model, data, model.key(resets.keyframe).id)
        mujoco.mj_forward(model, data)
    for i in range(NUM_ENVS):
        np.testing.assert_array_equal(out["qpos"][i].numpy(), datas[i].qpos)
    low, high = env.action_spec.space.low[0].numpy(), env.action_spec.space.high[0].numpy()
    for step in range(STEPS):
        if step == MID_EPISODE:  # the scales on envs 1 and 3, composing with env 1's own values
            write(_draw(mid_names, {}, rng), MID_MASK)
            for i in np.flatnonzero(MID_MASK).tolist():
                models[i] = reference_model(nominal, roles, per_env[i])  # same state, new model
        action = rng.uniform(low, high, size=(NUM_ENVS, nominal.nu)).astype(np.float32)
        out = env.step(TensorDict({"action": torch.from_numpy(action)}, [NUM_ENVS]))["next"]
        for i, (model, data) in enumerate(zip(models, datas, strict=True)):
            data.ctrl[:] = action[i]
            for _ in range(FRAME_SKIP):
                mujoco.mj_step(model, data)
            for key, expected in (("qpos", data.qpos), ("qvel", data.qvel), ("force", data.actuator_force)):
                np.testing.assert_array_equal(out[key][i].numpy(), expected, err_msg=f"{case} step {step} env {i}")
    assert not out["broken"].any()  # no env diverged: the trajectories compared are the servos'
    for i in range(NUM_ENVS):  # the model values the env wrote are the hand-set ones
        np.testing.assert_array_equal(env.batch.get_model(i).actuator_gainprm, models[i].actuator_gainprm)
        np.testing.assert_array_equal(env.batch.get_model(i).actuator_biasprm, models[i].actuator_biasprm)
    assert set(per_env[1]) == set(first_names) | set(mid_names)  # env 1 ran with both writes composed
    env.close()


def _arm(num_envs: int = 2) -> BatchedMujocoEnv:
    return BatchedMujocoEnv(ARM, num_envs, observation={"qpos": R.joint_pos()}, seed=0, num_threads=1)


def test_each_gain_is_offered_for_the_actuators_it_means_something_for() -> None:
    env = _arm()
    model = mujoco.MjModel.from_xml_string(ARM)
    fields = {field.name: field for field in env.domain_fields()}
    offered = {
        kind: sorted(name.split(":")[1] for name in fields if name.startswith(kind + ":"))
        for kind in ("actuator_kp", "actuator_kv", "actuator_gain", "actuator_gear")
    }
    assert offered == {
        "actuator_kp": ["elbow", "shoulder"],  # the position servos
        "actuator_kv": ["elbow", "shoulder", "wrist"],  # their damping (the shoulder's 0) and the velocity servo's
        "actuator_gain": ["slider"],  # the motor
        "actuator_gear": ["elbow", "shoulder", "slider", "wrist"],
    }
    nominals = {name: fields[name].nominal.item() for name in ("actuator_kp:shoulder", "actuator_kv:elbow")}
    nominals.update({name: fields[name].nominal.item() for name in ("actuator_kv:wrist", "actuator_gain:slider")})
    assert nominals == {
        "actuator_kp:shoulder": model.actuator("shoulder").gainprm[0],
        "actuator_kv:elbow": -model.actuator("elbow").biasprm[2],
        "actuator_kv:wrist": model.actuator("wrist").gainprm[0],
        "actuator_gain:slider": model.actuator("slider").gainprm[0],
    }
    assert fields["actuator_kv:shoulder"].nominal.item() == 0.0 and not fields["actuator_kv:shoulder"].nominal.signbit()
    rules = {name: fields[name].rule for name in fields if name.startswith(("actuator_k", "actuator_gain"))}
    assert {rules["actuator_kp:elbow"], rules["actuator_kp_scale"], rules["actuator_gain:slider"]} == {"in (0.0, inf)"}
    assert (rules["actuator_kv:wrist"], rules["actuator_kv_scale"]) == ("in [0.0, inf)", "in (0.0, inf)")
    assert fields["actuator_kp:elbow"].model_fields == ("actuator_gainprm", "actuator_biasprm")
    assert not any(fields[name].set_const for name in rules)  # mj_setConst reads neither gainprm nor biasprm
    for wrong, meant, has in [
        ("actuator_kp:slider", "'shoulder', 'elbow'", "actuator_gear:slider, actuator_gain:slider"),
        ("actuator_gain:elbow", "'slider'", "actuator_gear:elbow, actuator_kp:elbow, actuator_kv:elbow"),
    ]:
        actuator = wrong.split(":")[1]
        match = rf"actuator '{actuator}' has no domain field '{wrong}'.*\(here: {meant}\); '{actuator}' has {has}$"
        with pytest.raises(ValueError, match=match):
            env.domain_fields([wrong])
        with pytest.raises(ValueError, match=match):
            env.set_domain({wrong: torch.ones(2, dtype=torch.float64)})
    with pytest.raises(ValueError, match=r"unknown domain field 'actuator_kp:wirst'.*did you mean 'actuator_kv:wrist'"):
        env.domain_fields(["actuator_kp:wirst"])  # no such actuator: the closest names
    with pytest.raises(ValueError, match=r"'actuator_kp_scale' and 'actuator_kp:elbow' both write"):
        env.domain_fields(["actuator_kp_scale", "actuator_kp:elbow"])
    env.close()
    # other actuators: an integrated-velocity servo is a position servo on its activation (gainprm[0] = kp,
    # biasprm = [0, -kp, -kv]); a damper (an affine gain) and a cylinder (biasprm[1] != -gainprm[0]) have none of the
    # three; a model without servos offers no kp or kv scale
    others = BatchedMujocoEnv(
        '<mujoco><worldbody><body><joint name="a" axis="1 0 0"/><joint name="b" axis="0 1 0"/>'
        '<joint name="c" axis="0 0 1"/><joint name="d" type="slide"/>'
        '<geom size=".1" mass="1"/></body></worldbody><actuator><motor joint="a"/>'
        '<intvelocity name="iv" joint="b" kp="10" kv="2" actrange="-1 1"/><damper joint="c" kv="3" ctrlrange="0 1"/>'
        '<cylinder joint="d" area="2" bias="1 -3 -4"/></actuator></mujoco>',
        1,
        observation={"qpos": R.joint_pos()},
    )
    names = [field.name for field in others.domain_fields() if field.name.startswith(("actuator_k", "actuator_gain"))]
    assert names == [
        "actuator_kp:iv",
        "actuator_kp_scale",
        "actuator_kv:iv",
        "actuator_kv_scale",
        "actuator_gain:a",
        "actuator_gain_scale",
    ]
    assert others.domain_fields(["actuator_kv:iv"])[0].nominal.item() == 2.0
    others.close()
    motors = BatchedMujocoEnv(
        '<mujoco><worldbody><body><joint name="j"/><geom size=".1" mass="1"/></body></worldbody>'
        '<actuator><motor joint="j"/></actuator></mujoco>',
        1,
        observation={"qpos": R.joint_pos()},
    )
    names = [field.name for field in motors.domain_fields()]
    assert "actuator_gain:j" in names and not any(name.startswith(("actuator_kp", "actuator_kv")) for name in names)
    motors.close()


@pytest.mark.parametrize(
    ("name", "bad", "match"),
    [
        ("actuator_kp:shoulder", 0.0, r"'actuator_kp:shoulder'.* of env 1 is 0\.0.*must be in \(0\.0, inf\)"),
        ("actuator_kp:elbow", -5.0, r"'actuator_kp:elbow'.* of env 1 is -5\.0"),
        ("actuator_kv:wrist", -1.0, r"'actuator_kv:wrist'.* of env 1 is -1\.0.*must be in \[0\.0, inf\)"),
        ("actuator_gain:slider", 0.0, r"'actuator_gain:slider'.* of env 1 is 0\.0"),
        ("actuator_kv_scale", 0.0, r"'actuator_kv_scale'.* of env 1 is 0\.0.*must be in \(0\.0, inf\)"),
        ("actuator_gain_scale", float("nan"), r"'actuator_gain_scale'.* of env 1 is nan"),
    ],
)
def test_bad_gains_are_refused_naming_the_field_and_the_value(name: str, bad: float, match: str) -> None:
    env = _arm()
    values = torch.ones(2, dtype=torch.float64)
    values[1] = bad
    with pytest.raises(ValueError, match=match):
        env.set_domain({name: values})
    assert env.batch.expanded("actuator_gainprm") is None and env.batch.expanded("actuator_biasprm") is None
    env.close()


def test_gains_round_trip_through_a_checkpoint() -> None:
    env = _arm(3)
    env.set_domain({"actuator_kp:elbow": torch.tensor([5.0, 15.0, 30.0], dtype=torch.float64)})
    env.set_domain(
        {"actuator_kv_scale": torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)}, torch.tensor([1, 0, 1]) > 0
    )
    env.reset()
    state = env.state_dict()
    loaded = _arm(3)
    loaded.load_state_dict(state)
    assert set(loaded.domain_values()) == set(env.domain_values())
    for name, value in env.domain_values().items():
        assert torch.equal(loaded.domain_values([name])[name], value), name
    for field in ("actuator_gainprm", "actuator_biasprm"):
        np.testing.assert_array_equal(loaded.batch.expanded(field), env.batch.expanded(field))
    action = TensorDict({"action": torch.full((3, 4), 0.5)}, [3])
    assert torch.equal(loaded.step(action.clone())["next", "qpos"], env.step(action.clone())["next", "qpos"])
    env.close()
    loaded.close()


def test_a_domain_randomization_draws_the_kp_scale_per_env_at_reset() -> None:
    base = BatchedMujocoEnv(model_path("quadruped"), NUM_ENVS, observation={"qpos": R.joint_pos()},
                            resets=Resets(keyframe="home"), seed=0, num_threads=1)  # fmt: skip
    kp = mujoco.MjModel.from_xml_path(str(model_path("quadruped"))).actuator_gainprm[:, 0]
    env = TransformedEnv(base, DomainRandomization([UniformDomainParam("actuator_kp_scale", 1.0, 0.2)], seed=0))
    data = env.rollout(3)
    scale = data["next", "domain", "actuator_kp_scale"][:, -1, 0]
    assert ((scale >= 0.8) & (scale <= 1.2)).all() and scale.unique().numel() == NUM_ENVS
    written = scale.numpy()[:, None] * kp
    np.testing.assert_array_equal(base.batch.expanded("actuator_gainprm")[:, :, 0], written)
    np.testing.assert_array_equal(base.batch.expanded("actuator_biasprm")[:, :, 1], -written)
    env.close()
