"""Every perturbation at once, in TorchRL's layouts: resumed in a new process, refused across configurations,
ParallelEnv workers from a lambda, offline recomputation of the collected rewards.

The env (``tests/perturbed_env.py``): the velocity-tracking quadruped with an action queue, observation noise with
per-episode biases, pushes (velocity changes and held forces every 2-4 steps), a DomainRandomization of the action
delay, servo gains, masses and frictions at every reset, 12-step episodes and falls (partial resets), and a
BaseEnvState. Each perturbation's own semantics are checked against references from their definitions in
test_action_delay.py, test_observation_noise.py, test_pushes.py and test_batched_mujoco_gains.py.
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.collectors.utils import split_trajectories
from torchrl.envs import ParallelEnv

pytest.importorskip("mujoco")

from perturbed_env import make_collector, make_perturbed_env, make_policy
from repo_paths import TESTS
from storage_probe import StorageProbe
from torchtasks.stats import episode_statistics
from torchtasks.transforms import TaskTransform, collector_state, load_collector_state

pytestmark = pytest.mark.mujoco


def _assert_equal_batches(expected, actual) -> None:
    keys = sorted(expected.keys(True, True), key=str)
    assert keys == sorted(actual.keys(True, True), key=str)
    for key in keys:
        assert torch.equal(expected[key], actual[key]), key


def test_resume_in_a_new_process_continues_every_perturbation_bit_for_bit(tmp_path: Path) -> None:
    running = make_collector()
    batches = iter(running)
    next(batches)
    next(batches)
    torch.save(collector_state(running), tmp_path / "checkpoint.pt")
    expected = [next(batches) for _ in range(3)]
    running.shutdown()
    # the perturbations acted in the batches compared: pushes, held forces, delays and biases of several episodes
    pushed = torch.cat([batch["next", "push_velocity"] for batch in expected])
    assert (pushed.abs().sum(-1) > 0).sum() >= 3
    assert torch.cat([batch["next", "done"] for batch in expected]).any()
    code = textwrap.dedent(
        f"""
        import sys, torch
        sys.path.insert(0, {str(TESTS)!r})
        from perturbed_env import make_collector
        from torchtasks.transforms import load_collector_state
        resumed = make_collector()
        load_collector_state(resumed, torch.load({str(tmp_path / "checkpoint.pt")!r}))
        batches = iter(resumed)
        torch.save([next(batches) for _ in range(3)], {str(tmp_path / "resumed.pt")!r})
        resumed.shutdown()
        """
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    resumed = torch.load(tmp_path / "resumed.pt", weights_only=False)
    for want, got in zip(expected, resumed, strict=True):
        _assert_equal_batches(want, got)


#: checkpoints of other configurations and the module that refuses each: a transform in the middle of the
#: Compose before anything of it is written (no pushes), the base env through the last transform, BaseEnvState,
#: once every transform before it has loaded (another action queue), a transform after loading, by its check of
#: the loaded values (another number of envs)
OTHER_CONFIGURATIONS = {
    "no pushes": ({"pushes": False}, "Pushes"),
    # the facts that differ, not the whole declaration
    "another max_action_delay": (
        {"max_action_delay": 3},
        r"max_action_delay differ\): saved \{'max_action_delay': 3\}, this env \{'max_action_delay': 2\}; load",
    ),
    "another number of envs": ({"num_envs": 2}, "ObservationNoise.load_state_dict: the checkpoint holds values"),
}
#: how a checkpoint is loaded: torchtasks' resume, and TorchRL's own loads of a collector and of an env, which load
#: the transforms one after the other
LOADS = {
    "load_collector_state": lambda collector, other: load_collector_state(collector, collector_state(other)),
    "Collector.load_state_dict": lambda collector, other: collector.load_state_dict(other.state_dict()),
    "TransformedEnv.load_state_dict": lambda collector, other: collector.env.load_state_dict(other.env.state_dict()),
}


@pytest.mark.parametrize("load", list(LOADS))
@pytest.mark.parametrize("other", list(OTHER_CONFIGURATIONS))
def test_a_checkpoint_of_other_perturbations_is_refused_and_changes_nothing(other: str, load: str) -> None:
    keywords, refuser = OTHER_CONFIGURATIONS[other]
    saved = make_collector(**keywords)
    batches = iter(saved)
    next(batches), next(batches)  # a batch further than the other two: its generators and timers elsewhere
    refusing, untouched = make_collector(), make_collector()
    next(iter(refusing)), next(iter(untouched))  # mid-run: generators, timers, queues and biases all in use
    # load_collector_state refuses from the carried data when they differ, before any module
    with pytest.raises(ValueError, match=refuser if load != "load_collector_state" else None):
        LOADS[load](refusing, saved)
    _assert_equal_batches(next(iter(untouched)), next(iter(refusing)))
    for collector in (saved, refusing, untouched):
        collector.shutdown()


def test_collected_rewards_recompute_offline_from_the_data() -> None:
    """The task judged the policy's action and the true states online; the data holds both, so the rewards,
    flags and terms recompute offline equal, though the physics ran delayed actions and the policy saw noise."""
    collector = make_collector()
    batches = iter(collector)
    batch = torch.cat([next(batches) for _ in range(4)])
    task = next(t for t in collector.env.transform if isinstance(t, TaskTransform))
    assert not torch.equal(batch["next", "applied_action"], batch["action"])  # the delay acted
    online = batch["next"].clone()
    for key in [task.reward_key, "failure", "terminated", "done", *task.term_keys]:
        batch["next", key] = torch.zeros_like(online[key])  # what the offline pass must write back
    task(batch)
    for key in [task.reward_key, "failure", "terminated", "done", *task.term_keys]:
        assert torch.equal(batch["next", key], online[key]), key
    assert online[task.reward_key].abs().sum() > 0 and online["terminated"].any()
    collector.shutdown()


def test_no_entry_of_a_step_shares_storage_with_another_frames() -> None:
    """Every perturbation's entries (the applied action, the noise biases, the pushes, the drawn values) are new
    tensors at every step, in a rollout and in a Collector: a write into one frame's data changes no other frame."""
    env = make_perturbed_env()
    probe = StorageProbe()
    env.append_transform(probe)
    env.rollout(8, make_policy(env), break_when_any_done=False)
    assert not probe.found, probe.found[:4]
    collector = Collector(env, make_policy(env), frames_per_batch=24, total_frames=48)
    for _ in collector:
        pass
    collector.shutdown()
    assert probe._steps == 8 + 16 and not probe.found, probe.found[:4]


def test_statistics_count_the_pushes_and_the_biases_in_every_layout() -> None:
    """``push_steps_mean/<kind>`` and ``observation_bias_rms/<entry>`` equal a count frame by frame of a Collector's
    batches, time-major, flat (a replay buffer's view) and split into trajectories alike."""
    collector = make_collector(4)
    batches = iter(collector)
    data = torch.cat([next(batches) for _ in range(8)], -1)  # [4 envs, 96 steps] of 12-step episodes
    collector.shutdown()
    nxt = data["next"]
    rows, steps = data.batch_size
    sums = {"velocity": [], "wrench": []}
    squares = {"gravity": [], "joint_pos": []}
    lengths = []
    for row in range(rows):
        for t in range(steps):
            if not bool(nxt["done"][row, t]):
                continue
            for name in squares:
                squares[name] += [float(v) ** 2 for v in nxt[f"observation_bias_{name}"][row, t]]
            length = int(nxt["step_count"][row, t])
            lengths.append(length)
            if t - length + 1 >= 0:  # a complete episode
                for kind in sums:
                    pushed = nxt[f"push_{kind}"][row, t - length + 1 : t + 1]
                    sums[kind].append(sum(bool(frame.any()) for frame in pushed))
    expected = {f"push_steps_mean/{kind}": sum(counts) / len(counts) for kind, counts in sums.items()}
    expected.update({f"observation_bias_rms/{n}": math.sqrt(sum(v) / len(v)) for n, v in squares.items()})
    assert len(sums["velocity"]) >= 6 and expected["push_steps_mean/velocity"] > 1
    assert min(lengths) < 12 <= max(lengths)  # falls and time limits: partial resets
    layouts = {
        "time-major": data,
        "flat": data.reshape(-1),
        "split_trajs": split_trajectories(data.clone()),
    }
    for layout, arranged in layouts.items():
        stats = episode_statistics(arranged)
        for key, value in expected.items():
            assert math.isclose(stats[key], value, rel_tol=1e-9), (layout, key, stats[key], value)


def _worker() -> object:
    return make_perturbed_env(2)


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
@pytest.mark.filterwarnings("ignore:A lambda function was passed to ParallelEnv")  # the layout under test
def test_parallel_env_workers_from_a_lambda_draw_their_own_perturbations_and_repeat_under_a_seed(
    fork_start_method,
) -> None:
    def rollout(seed: int) -> object:
        env = ParallelEnv(2, lambda: _worker())
        env.set_seed(seed)
        policy = make_policy(make_perturbed_env(1))
        data = env.rollout(8, policy, break_when_any_done=False)
        env.close()
        return data

    first, again, other = rollout(5), rollout(5), rollout(6)
    _assert_equal_batches(first, again)
    for key in [("next", "observation_bias_joint_pos"), ("next", "domain", "actuator_kp_scale")]:
        assert not torch.equal(first[key][0], first[key][1]), key  # the workers' streams differ
        assert not torch.equal(first[key], other[key]), key  # another seed, other draws
