"""Pushes and external forces: the engine's writes, the Pushes transform, its run state and its domain fields.

The reference of every trajectory is one ``mujoco.MjData`` per env, reset with ``mj_resetData`` when the env resets
and stepped with ``mj_step`` ``frame_skip`` times, given the push of the definition before the step's physics:
``qvel[free joint] += delta``, and ``xfrc_applied[body] = wrench`` while a force is held (zeros otherwise). The
pushes themselves (which env, when, what) come from :class:`ReferencePushes`, written from the docstring of
``Pushes``: timers drawn from ``randint(low, high + 1)`` at each env's reset and after each push, counted down
before each step, a push where one runs out; the draws of a step with pushes (uniforms for velocity and force in
one draw, then timers) for all envs.
"""

from __future__ import annotations

import copy
import io

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")

import mujoco
from tensordict import TensorDict
from torchrl.envs import Compose, SerialEnv, StepCounter, TransformedEnv

from torchtasks.domain import DomainEnv, UniformDomainParam
from torchtasks.envs import BatchedMujocoEnv, PendulumEnv, readings
from torchtasks.envs.models import model_path
from torchtasks.transforms import BaseEnvState, DomainRandomization, Pushes, derived_seed

pytestmark = pytest.mark.mujoco

NUM_ENVS = 4
FRAME_SKIP = 2
STEPS = 20
MAX_STEPS = 6  # StepCounter: truncations, staggered by a partial reset after step PARTIAL_AT
PARTIAL_AT, PARTIAL_MASK = 2, [True, False, True, False]
INTERVAL, DURATION = (2, 5), 3
VELOCITY = [0.4, 0.3, 0.2, 0.5, 0.6, 0.7]
FORCE = [30.0, 20.0, 10.0, 2.0, 3.0, 1.0]
SMALL_XML = """<mujoco><worldbody><body name="box"><freejoint/><geom size="0.1"/>
  <body name="arm"><joint name="hinge"/><geom size="0.05" pos="0 0 0.2"/></body></body></worldbody>
  <actuator><motor joint="hinge"/></actuator></mujoco>"""


def quadruped(num_envs: int = NUM_ENVS) -> BatchedMujocoEnv:
    observation = {"qpos": readings.joint_pos(), "qvel": readings.joint_vel()}
    return BatchedMujocoEnv(model_path("quadruped"), num_envs, observation=observation, frame_skip=FRAME_SKIP, seed=0)


def pushed_env(seed: int = 7, *, state: bool = False, **kwargs) -> TransformedEnv:
    pushes = Pushes(
        "torso", velocity=VELOCITY, force=FORCE, duration=DURATION, interval_steps=INTERVAL, seed=seed, **kwargs
    )
    return TransformedEnv(quadruped(), Compose(StepCounter(MAX_STEPS), pushes, *([BaseEnvState()] if state else [])))


class ReferencePushes:
    """The pushes of the definition (Pushes' docstring), with the transform's seed: per env timers, draws, forces."""

    def __init__(self, seed: int, half_widths: dict[str, torch.Tensor]) -> None:
        self.generator = torch.Generator().manual_seed(seed)
        self.velocity, self.force = half_widths["velocity"], half_widths["force"]
        self.steps_left = torch.zeros(NUM_ENVS, dtype=torch.int64)
        self.held = torch.zeros(NUM_ENVS, dtype=torch.int64)
        self.wrench = torch.zeros(NUM_ENVS, 6, dtype=torch.float64)

    def reset(self, mask: torch.Tensor) -> None:
        timers = torch.randint(INTERVAL[0], INTERVAL[1] + 1, (NUM_ENVS,), generator=self.generator)
        self.steps_left[mask] = timers[mask]
        self.held[mask] = 0
        self.wrench[mask] = 0.0

    def before_step(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The velocity change of this step and whether each env pushes."""
        self.steps_left -= 1
        fired = self.steps_left <= 0
        ending = self.held == 1
        self.held = (self.held - 1).clamp(min=0)
        delta = torch.zeros(NUM_ENVS, 6, dtype=torch.float64)
        if (fired | ending).any():
            unit = torch.rand(NUM_ENVS, 12, generator=self.generator, dtype=torch.float64)  # velocity, then force
            delta[fired] = ((2 * unit[:, :6] - 1) * self.velocity)[fired]
            self.wrench[ending] = 0.0
            self.wrench[fired] = ((2 * unit[:, 6:] - 1) * self.force)[fired]
            self.held[fired] = DURATION
            timers = torch.randint(INTERVAL[0], INTERVAL[1] + 1, (NUM_ENVS,), generator=self.generator)
            self.steps_left[fired] = timers[fired]
        return delta, fired


def test_pushes_equal_per_env_mujoco_with_partial_resets() -> None:
    env = pushed_env()
    pushes = env.transform[1]
    model = env.base_env.model
    torso, free = model.body("torso").id, slice(0, 6)  # the torso's free joint: the first 6 dofs
    # per-env ranges (domain fields): env 3 is never pushed by a velocity change
    velocity = torch.tensor(VELOCITY, dtype=torch.float64) * torch.tensor([[1.0], [2.0], [0.5], [0.0]])
    pushes.set_domain({"push_velocity:torso": velocity})
    reference = ReferencePushes(7, {"velocity": velocity, "force": torch.tensor(FORCE, dtype=torch.float64)})
    datas = [mujoco.MjData(model) for _ in range(NUM_ENVS)]
    actions = torch.Generator().manual_seed(0)

    def reset(mask: torch.Tensor) -> None:
        reference.reset(mask)
        for i in np.flatnonzero(mask.numpy()).tolist():
            mujoco.mj_resetData(model, datas[i])

    td = env.reset()
    reset(torch.ones(NUM_ENVS, dtype=torch.bool))
    pushed_steps: list[list[int]] = [[] for _ in range(NUM_ENVS)]
    episode_start = [0] * NUM_ENVS
    for t in range(STEPS):
        if t == PARTIAL_AT:
            mask = torch.tensor(PARTIAL_MASK)
            td = env.reset(td.set("_reset", mask.unsqueeze(-1)))
            reset(mask)
            for i in np.flatnonzero(PARTIAL_MASK).tolist():
                episode_start[i] = t
        action = (torch.rand(NUM_ENVS, model.nu, generator=actions) - 0.5).to(torch.float32)
        delta, fired = reference.before_step()
        for i, data in enumerate(datas):
            data.qvel[free] += delta[i].numpy() if fired[i] else 0.0
            data.xfrc_applied[torso] = reference.wrench[i].numpy()
            data.ctrl[:] = action[i].double().numpy()
            for _ in range(FRAME_SKIP):
                mujoco.mj_step(model, data)
        out, td = env.step_and_maybe_reset(td.set("action", action))
        step = out["next"]
        assert torch.equal(step["push_velocity"], delta), t
        assert torch.equal(step["push_wrench"], reference.wrench), t
        assert np.array_equal(step["qpos"].numpy(), np.stack([d.qpos for d in datas])), t
        assert np.array_equal(step["qvel"].numpy(), np.stack([d.qvel for d in datas])), t
        for i in np.flatnonzero(fired.numpy()).tolist():
            pushed_steps[i].append(t - episode_start[i])
        done = step["done"].reshape(NUM_ENVS)
        if done.any():
            reset(done)
            for i in np.flatnonzero(done.numpy()).tolist():
                pushed_steps[i].append(-1)  # an episode's end
                episode_start[i] = t + 1
    # the definition's timing per env: the first push of an episode at its step k, then k steps apart, k in INTERVAL
    for i, steps in enumerate(pushed_steps):
        episode: list[int] = []
        for step_index in [*steps, -1]:
            if step_index == -1:
                gaps = np.diff([-1, *episode])
                assert ((gaps >= INTERVAL[0]) & (gaps <= INTERVAL[1])).all(), (i, steps)
                episode = []
            else:
                episode.append(step_index)
    assert sum(len(s) for s in pushed_steps) > NUM_ENVS * 3  # pushes happened, across partial resets
    assert torch.equal(pushes.steps_left, reference.steps_left)
    env.close()


def test_engine_writes_masked_rows_that_resets_clear_and_checkpoints_keep() -> None:
    env = quadruped(3)
    td = env.reset()
    qvel, xfrc = env.batch.bind("qvel"), env.batch.bind("xfrc_applied")
    torso = env.model.body("torso").id
    mask = torch.tensor([True, False, True])
    delta = torch.arange(18, dtype=torch.float64).reshape(3, 6) / 10
    before = qvel.copy()
    env.add_body_velocity("torso", delta, mask)
    expected = before.copy()
    expected[[0, 2], :6] = before[[0, 2], :6] + delta.numpy()[[0, 2]]
    assert np.array_equal(qvel, expected)
    wrench = torch.full((3, 6), 4.0, dtype=torch.float64)
    env.set_body_wrench("torso", wrench, mask)
    assert xfrc[:, torso].tolist() == [[4.0] * 6, [0.0] * 6, [4.0] * 6]
    assert not xfrc[:, :torso].any() and not xfrc[:, torso + 1 :].any()
    action = torch.zeros(3, env.model.nu)
    td = env.step(td.set("action", action))["next"]
    assert xfrc[:, torso].tolist() == [[4.0] * 6, [0.0] * 6, [4.0] * 6]  # held across steps
    buffer = io.BytesIO()
    torch.save(env.state_dict(), buffer)
    buffer.seek(0)
    resumed = quadruped(3)
    resumed.load_state_dict(torch.load(buffer, weights_only=False))
    assert np.array_equal(resumed.batch.bind("xfrc_applied"), xfrc)
    for _ in range(3):  # the resumed env continues the held wrench bit for bit
        a = env.step(td.clone().set("action", action))["next"]
        b = resumed.step(td.clone().set("action", action))["next"]
        assert torch.equal(a["qpos"], b["qpos"]) and torch.equal(a["qvel"], b["qvel"])
    env.reset(TensorDict({"_reset": torch.tensor([[True], [False], [False]])}, batch_size=[3]))
    assert xfrc[:, torso].tolist() == [[0.0] * 6, [0.0] * 6, [4.0] * 6]  # the reset env's wrench is gone
    env.close()
    resumed.close()


def test_engine_refuses_bad_bodies_shapes_and_dtypes() -> None:
    env = quadruped(2)
    good = torch.zeros(2, 6, dtype=torch.float64)
    assert env.pushable_bodies() == ("torso",)
    with pytest.raises(ValueError, match=r"'torsoo' is not a body.*did you mean 'torso'"):
        env.add_body_velocity("torsoo", good)
    with pytest.raises(ValueError, match="'FL_hip' is a body without a free joint"):
        env.add_body_velocity("FL_hip", good)
    with pytest.raises(ValueError, match="did you mean 'torso'"):
        env.set_body_wrench("torsoo", good)
    with pytest.raises(ValueError, match="is the world"):
        env.set_body_wrench("world", good)
    with pytest.raises(TypeError, match=r"delta must be a float64 tensor of shape \[2, 6\].*float32"):
        env.add_body_velocity("torso", good.float())
    with pytest.raises(ValueError, match=r"wrench must be a float64 tensor of shape \[2, 6\].*got shape \[2, 3\]"):
        env.set_body_wrench("torso", good[:, :3])
    with pytest.raises(ValueError, match="finite in the rows of the envs in mask"):
        env.add_body_velocity("torso", torch.full((2, 6), float("nan"), dtype=torch.float64))
    env.add_body_velocity("torso", torch.full((2, 6), float("nan"), dtype=torch.float64), torch.tensor([False, False]))
    with pytest.raises(ValueError, match=r"mask must be a bool tensor of shape \[2\]"):
        env.set_body_wrench("torso", good, torch.tensor([1, 0]))
    assert not env.batch.bind("xfrc_applied").any() and not env.batch.bind("qvel").any()  # nothing was written
    env.close()


def test_resume_in_a_new_env_continues_bit_for_bit_and_other_configurations_are_refused() -> None:
    running = pushed_env(3, state=True)
    actions = torch.Generator().manual_seed(1)
    nu = running.base_env.model.nu

    def step(env: TransformedEnv, td: TensorDict, action: torch.Tensor) -> tuple[TensorDict, TensorDict]:
        return env.step_and_maybe_reset(td.clone().set("action", action))

    td = running.reset()
    for _ in range(9):
        _, td = step(running, td, torch.rand(NUM_ENVS, nu, generator=actions).to(torch.float32) - 0.5)
    pushes = running.transform[1]
    assert bool((pushes.force_steps_left > 0).any())  # a force is held at the checkpoint
    buffer = io.BytesIO()
    torch.save(running.state_dict(), buffer)
    saved = buffer.getvalue()
    resumed = pushed_env(99, state=True)  # another seed: the checkpoint's generator takes over
    resumed.load_state_dict(torch.load(io.BytesIO(saved), weights_only=False))
    carried = td.clone()
    with pytest.warns(UserWarning, match="without a reset"):  # the carried data are given by hand here
        for _ in range(8):
            action = torch.rand(NUM_ENVS, nu, generator=actions).to(torch.float32) - 0.5
            (a, td), (b, carried) = step(running, td, action), step(resumed, carried, action)
            assert (a == b).all(), "the resumed run differs"
    # a checkpoint of another configuration is refused, and changes nothing
    state = torch.load(io.BytesIO(saved), weights_only=False)
    own = {k[len("transforms.1.") :]: v for k, v in state.items() if k.startswith("transforms.1.")}
    for other, differs in (
        (Pushes("torso", velocity=VELOCITY, force=FORCE, duration=DURATION, interval_steps=(2, 6)), "interval_steps"),
        (Pushes("torso", velocity=VELOCITY, duration=DURATION, interval_steps=INTERVAL), "kinds"),
        (Pushes("torso", velocity=VELOCITY, force=FORCE, duration=2, interval_steps=INTERVAL), "duration"),
        (Pushes("box", velocity=VELOCITY, force=FORCE, duration=DURATION, interval_steps=INTERVAL), "body"),
    ):
        before = copy.deepcopy(other.state_dict())
        with pytest.raises(ValueError, match=f"other pushes.*{differs}: saved"):
            other.load_state_dict(own)
        after = other.state_dict()
        assert after.keys() == before.keys() and all(
            torch.equal(after[k], before[k]) for k in before if isinstance(before[k], torch.Tensor)
        )
    target = resumed.transform[1]
    before = copy.deepcopy(target.state_dict())
    bad = dict(own, velocity_half_widths=-own["velocity_half_widths"] - 1.0)  # a range a draw cannot use
    with pytest.raises(ValueError, match="'velocity_half_widths' must be finite and >= 0"):
        target.load_state_dict(bad)
    assert all(torch.equal(v, before[k]) for k, v in target.state_dict().items() if isinstance(v, torch.Tensor))
    assert torch.equal(target.generator.get_state(), before["_extra_state"]["generator_state"])
    running.close()
    resumed.close()


def make_small_env() -> TransformedEnv:
    base = BatchedMujocoEnv(SMALL_XML, 2, observation=readings.joint_vel("hinge"), seed=0)
    return TransformedEnv(base, Pushes("box", velocity=[1.0] * 6, interval_steps=(1, 3)))


def test_set_seed_seeds_each_worker_and_repeats_with_the_same_seed() -> None:
    single = make_small_env()
    single.set_seed(11)
    pushes = single.transform
    assert pushes.generator.initial_seed() == derived_seed(11, 0, "Pushes('box', 'push')")
    runs = []
    for seed in (5, 5, 6):
        env = SerialEnv(2, make_small_env)
        env.set_seed(seed)
        runs.append(env.rollout(6, break_when_any_done=False)["next", "push_velocity"])
        env.close()
    assert torch.equal(runs[0], runs[1])  # the same seed, the same pushes
    assert not torch.equal(runs[0], runs[2])
    assert not torch.equal(runs[0][0], runs[0][1])  # each worker its own stream
    single.close()


def test_build_and_setup_refusals() -> None:
    with pytest.raises(ValueError, match=r"velocity must be finite half-widths >= 0"):
        Pushes("torso", velocity=[0.1, -0.1, 0, 0, 0, 0], interval_steps=3)
    with pytest.raises(ValueError, match=r"force must hold 6 half-widths.*\[3\]"):
        Pushes("torso", force=[1.0, 1.0, 1.0], interval_steps=3)
    with pytest.raises(ValueError, match=r"1 <= low <= high, got \(5, 2\)"):
        Pushes("torso", velocity=VELOCITY, interval_steps=(5, 2))
    with pytest.raises(ValueError, match=r"1 <= low <= high, got \(0, 2\)"):
        Pushes("torso", velocity=VELOCITY, interval_steps=(0, 2))
    with pytest.raises(ValueError, match="duration must be a positive int, got 0"):
        Pushes("torso", force=FORCE, duration=0, interval_steps=3)
    with pytest.raises(ValueError, match="exactly one of interval_steps"):
        Pushes("torso", velocity=VELOCITY, interval_steps=3, interval_seconds=(0.1, 0.2))
    with pytest.raises(ValueError, match="0 < low <= high"):
        Pushes("torso", velocity=VELOCITY, interval_seconds=(0.0, 0.2))
    with pytest.raises(ValueError, match=r"velocity= .* and/or force="):
        Pushes("torso", interval_steps=3)
    with pytest.raises(ValueError, match=r"body 'robot/torso' holds '\.' or '/'"):
        Pushes("robot/torso", velocity=VELOCITY, interval_steps=3)
    with pytest.raises(TypeError, match="body must be"):
        Pushes(3, velocity=VELOCITY, interval_steps=3)  # type: ignore[arg-type]
    # at the env (its specs, the first reset): a body without a free joint, an env that cannot push, no whole step
    with pytest.raises(ValueError, match=r"'FL_hip' has no free joint.*pushable bodies: \['torso'\]"):
        TransformedEnv(quadruped(2), Pushes("FL_hip", velocity=VELOCITY, interval_steps=3)).reset()
    with pytest.raises(ValueError, match=r"no body 'torsoo'; did you mean 'torso'"):  # a force: any body of the model
        TransformedEnv(quadruped(2), Pushes("torsoo", force=FORCE, interval_steps=3)).reset()
    with pytest.raises(TypeError, match="base env must offer pushable_bodies"):
        TransformedEnv(PendulumEnv(batch_size=[2]), Pushes("torso", velocity=VELOCITY, interval_steps=3)).reset()
    with pytest.raises(ValueError, match=r"no whole number of steps >= 1 .*dt=0.01"):
        TransformedEnv(quadruped(2), Pushes("torso", velocity=VELOCITY, interval_seconds=(0.013, 0.019))).reset()
    # seconds convert to the whole steps of the range, a bound within rounding of a step included (0.07 / 0.01)
    env = TransformedEnv(quadruped(2), Pushes("torso", force=FORCE, interval_seconds=(0.025, 0.07)))
    assert env.transform.steps_range() == (3, 7)
    env.close()


def test_domain_fields_of_the_push_ranges() -> None:
    pushes = Pushes("torso", velocity=VELOCITY, force=FORCE, interval_steps=3)
    assert isinstance(pushes, DomainEnv)
    velocity, force = pushes.domain_fields()
    assert (velocity.name, force.name) == ("push_velocity:torso", "push_force:torso")
    assert velocity.value_shape == (6,) and velocity.nominal.tolist() == VELOCITY and force.nominal.tolist() == FORCE
    assert (velocity.low, velocity.low_open, velocity.model_fields) == (0.0, False, ())
    with pytest.raises(ValueError, match=r"unknown domain field 'push_velocity:torsoo'.*did you mean"):
        pushes.domain_fields(["push_velocity:torsoo"])
    with pytest.raises(ValueError, match="put the transform into an env first"):
        pushes.domain_values()
    env = TransformedEnv(quadruped(3), pushes)
    assert pushes.domain_values()["push_force:torso"].tolist() == [FORCE] * 3
    wider = torch.full((3, 6), 2.0, dtype=torch.float64)
    pushes.set_domain({"push_force:torso": wider}, torch.tensor([False, True, False]))
    assert pushes.domain_values(["push_force:torso"])["push_force:torso"].tolist() == [FORCE, [2.0] * 6, FORCE]
    negative = wider.clone()
    negative[2, 0] = -1.0
    with pytest.raises(ValueError, match=r"values\['push_force:torso'\] of env 2 .* must be in \[0.0, inf\)"):
        pushes.set_domain({"push_force:torso": negative})
    with pytest.raises(TypeError, match="float64"):
        pushes.set_domain({"push_force:torso": wider.float()})
    assert pushes.domain_values()["push_force:torso"][2].tolist() == FORCE  # a refused write changes nothing
    env.close()


def test_domain_randomization_draws_the_push_ranges_per_env_and_episode() -> None:
    pushes = Pushes("torso", velocity=[0.1] * 6, interval_steps=(1, 2), seed=0)
    mean = torch.full((6,), 2.0, dtype=torch.float64)
    ranges = DomainRandomization([UniformDomainParam("push_velocity:torso", mean=mean, halfspan=1.0)], seed=1)
    env = TransformedEnv(quadruped(3), Compose(StepCounter(4), pushes, ranges))
    data = env.rollout(12, break_when_any_done=False)
    half_widths, velocity = data["next", "domain", "push_velocity:torso"], data["next", "push_velocity"]
    assert bool((velocity.abs() <= half_widths).all())  # each push within its env's drawn range
    assert bool((velocity.abs() > 0.1).any())  # beyond the nominal range: the drawn ones were used
    assert not torch.equal(half_widths[:, 0], half_widths[:, 4])  # a new range per episode (reset every 4 steps)
    assert torch.equal(pushes.domain_values()["push_velocity:torso"], half_widths[:, -1])
    env.close()


# ------------------------------------------------------------------------------------------------ contact readings
_RESTING = """<mujoco><option timestep="0.005"/><worldbody><geom type="plane" size="5 5 .1"/>
  <body name="box" pos="0 0 .1"><freejoint/><geom type="box" size=".1 .1 .1" mass="2"/>
    <body name="arm" pos=".2 0 0"><joint name="hinge" axis="0 1 0"/><geom size=".05" mass=".5"/></body></body>
  </worldbody><actuator><motor joint="hinge"/></actuator></mujoco>"""


def test_a_contact_reading_without_applied_forces_is_mujocos_contacts_alone() -> None:
    """MuJoCo's cfrc_ext holds the contacts plus xfrc_applied moved to the com-based frame; contact_force(...,
    applied=False) equals cfrc_ext recomputed by MuJoCo from the same contacts with nothing applied, and the default
    reading equals cfrc_ext as is (references: MjData, mj_rnePostConstraint)."""
    model = mujoco.MjModel.from_xml_string(_RESTING)
    data = mujoco.MjData(model)
    for _ in range(40):  # let the box settle on the plane
        mujoco.mj_step(model, data)
    data.xfrc_applied[1] = [5.0, -3.0, -20.0, 0.4, -0.2, 0.3]  # pushed into the floor: the contacts change too
    data.xfrc_applied[2] = [0.0, 2.0, 1.0, 0.1, 0.0, 0.0]
    mujoco.mj_step(model, data)
    mujoco.mj_rnePostConstraint(model, data)
    assert data.ncon > 0
    arrays = {name: getattr(data, name)[None].copy() for name in ("cfrc_ext", "xfrc_applied", "xipos", "subtree_com")}
    reference = copy.copy(data)
    reference.xfrc_applied[:] = 0.0
    mujoco.mj_rnePostConstraint(model, reference)  # the same contact forces (efc_force), nothing applied
    without = readings.contact_force("box", "arm", applied=False).resolve(model)
    with_applied = readings.contact_force("box", "arm").resolve(model)
    np.testing.assert_allclose(without.compute(arrays)[0], reference.cfrc_ext[1:3].ravel(), atol=1e-9)
    np.testing.assert_allclose(with_applied.compute(arrays)[0], data.cfrc_ext[1:3].ravel(), atol=0)
    assert np.abs(data.cfrc_ext[1:3] - reference.cfrc_ext[1:3]).max() > 1.0  # the push shows in cfrc_ext


def test_a_force_push_of_the_torso_is_no_base_contact() -> None:
    """The velocity-tracking task ends an episode on a torso contact: a force on the standing robot's torso (held
    for 3 steps, every 5 steps) pushes it but ends no episode; without the correction every push would."""
    from torchtasks.envs import velocity_tracking_env

    pushes = Pushes("torso", force=[30.0, 30.0, 30.0, 1.0, 1.0, 1.0], duration=3, interval_steps=5, seed=0)
    env = velocity_tracking_env(4, seed=0, perturbations=[pushes])
    data = env.rollout(20, lambda td: td.set("action", torch.zeros(4, 12)), break_when_any_done=False)
    pushed = (data["next", "push_wrench"] != 0).any(-1)
    assert pushed.sum() >= 4 * 9
    assert not data["next", "ended_by", "base_contact"].any()
    assert (data["next", "base_contact"][pushed] == 0).all()
    env.close()
