"""Run state in every layout: the data says what the env simulates, seeds repeat, frames share no storage, shards.

- The ``(domain, <field>)`` entries, at the root and under ``"next"`` of every frame, equal the physics the env ran
  (recomputed with the pendulum's dynamics), for every ``when`` and stored set, in a plain ``step_and_maybe_reset``
  loop, ``env.rollout``, a ``Collector`` of the env, of a ``SerialEnv`` and of a ``ParallelEnv`` (shared buffers) and
  a ``MultiSyncCollector``, each seeded after its envs were reset (a collector resets its env when it is built).
- A run repeats from its first frame when it is reset after ``set_seed``, whatever came before (torch's global
  stream, earlier batches, an earlier run of the same seed).
- No entry under ``"next"`` shares storage with an entry of the root of its frame or of the previous step, for every
  feature of ``feature_envs`` (every stateful transform), in ``env.rollout``, a ``Collector`` and ``ParallelEnv``
  workers with shared buffers, where the goal the task judged with stays the one the policy saw.
- ``DomainRandomization(..., shard=(k, n))``: ``n`` workers together take every domain of a given set once per pass.
"""

from __future__ import annotations

import functools
import io
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs import Compose, ParallelEnv, SerialEnv, StepCounter, TransformedEnv

from feature_envs import DOMAIN_MODES, FEATURES, domain_modes, pendulum_policy
from storage_probe import ALIASES, StorageProbe, probed
from torchtasks.domain import UniformDomainParam
from torchtasks.envs import PendulumEnv, pendulum_dynamics
from torchtasks.transforms import DomainRandomization

FIELDS = ("mass", "length", "gravity")
BATCH = 4  # envs in all: two workers of two in the batched layouts
STEPS = 12  # frames per env and batch; StepCounter(12) in the factory, episodes end by success too
SEED = 7


# ------------------------------------------------------------------------------------------------ layouts
def _loop(make: Callable[[], TransformedEnv]) -> TensorDictBase:
    """reset, set_seed, then the loop users write: ``step_and_maybe_reset`` (partial resets) with a policy."""
    env, policy = make(), pendulum_policy()
    tensordict = env.reset()
    env.set_seed(SEED)
    frames = []
    for _ in range(2 * STEPS):
        frame, tensordict = env.step_and_maybe_reset(policy(tensordict))
        frames.append(frame)
    env.close()
    return torch.stack(frames, -1)


def _rollout(make: Callable[[], TransformedEnv]) -> TensorDictBase:
    env = make()
    tensordict = env.reset()
    env.set_seed(SEED)
    data = env.rollout(2 * STEPS, pendulum_policy(), auto_reset=False, tensordict=tensordict, break_when_any_done=False)
    env.close()
    return data


def _two_batches(collector) -> TensorDictBase:
    """``collector.set_seed`` (after the reset of its construction), then two batches, rows of envs, time last."""
    try:
        collector.set_seed(SEED)
        batches = iter(collector)
        data = [next(batches).clone() for _ in range(2)]
    finally:
        collector.shutdown()
    return torch.cat([batch.reshape(-1, STEPS) for batch in data], -1)


def _collector(env) -> Collector:
    return Collector(
        env, pendulum_policy(), frames_per_batch=BATCH * STEPS, total_frames=-1, auto_register_policy_transforms=False
    )


def _collected(make: Callable[[], TransformedEnv]) -> TensorDictBase:
    return _two_batches(_collector(make()))


def _serial(makes: list[Callable[[], TransformedEnv]]) -> TensorDictBase:
    return _two_batches(_collector(SerialEnv(len(makes), makes)))


def _parallel(makes: list[Callable[[], TransformedEnv]]) -> TensorDictBase:
    return _two_batches(_collector(ParallelEnv(len(makes), makes)))  # shared buffers


def _multi_sync(makes: list[Callable[[], TransformedEnv]]) -> TensorDictBase:
    return _two_batches(MultiSyncCollector(makes, pendulum_policy(), frames_per_batch=BATCH * STEPS, total_frames=-1))


#: the layouts of one env, and of workers (one per set of modes: every set in one run)
ONE_ENV = {"loop": _loop, "rollout": _rollout, "collector": _collected}
PROCESSES = {"parallel_env": _parallel, "multi_sync": _multi_sync}
WORKERS = [functools.partial(domain_modes, BATCH // 2, 0, modes) for modes in DOMAIN_MODES]
WORKER_ROWS = [modes for modes in DOMAIN_MODES for _ in range(BATCH // 2)]  # each row's (env's) set of modes


# ------------------------------------------------------------------------------------------------ the physics
def _values(data: TensorDictBase, *key: str) -> torch.Tensor:
    return data[key].reshape(data.shape)


def _entries_are_the_physics(data: TensorDictBase, rows: list[str], layout: str) -> None:
    """Under "next", the values the step ran with (the pendulum's dynamics recomputed with them give the next state);
    at the root, the values the env held when it gave the frame's state: those of the step (reset and startup
    draws change nothing during an episode; the first frame follows a reset); with ``when="interval"`` (a draw comes
    before the step it applies to) those of the previous step inside an episode, and at a reset those of the previous
    step or, when the reset drew (an env's first reset after ``set_seed``), those of the step. ``rows``: each row's
    set of modes (a key of ``DOMAIN_MODES``)."""
    ran = {name: _values(data, "next", "domain", name) for name in FIELDS}
    expected = pendulum_dynamics(
        data["observation"],
        data["action"].clamp(-2.0, 2.0),
        dt=0.05,
        max_speed=8.0,
        **{name: values.to(torch.float32) for name, values in ran.items()},
    )
    wrong = (data["next", "observation"] != expected).any(-1)
    assert not wrong.any(), f"{layout}: the next state is not the dynamics' at (env, frame) {wrong.nonzero()[:5]}"
    inside = _values(data, "step_count") > 0
    for name in FIELDS:
        root = _values(data, "domain", name)
        before = torch.cat([ran[name][:, :1], ran[name][:, :-1]], -1)
        stale = root != ran[name]
        interval = torch.tensor([DOMAIN_MODES[modes][name]["when"] == "interval" for modes in rows]).unsqueeze(-1)
        stale = torch.where(interval, torch.where(inside, root != before, stale & (root != before)), stale).nonzero()
        assert not len(stale), f"{layout}: the root's {name!r} is not the env's at (env, frame) {stale[:5]}"
        assert ran[name].unique().numel() > 1, f"{layout}: {name!r} was not drawn"


def test_the_entries_are_the_physics_the_env_ran_after_set_seed():
    for modes in DOMAIN_MODES:
        for layout, collect in ONE_ENV.items():
            data = collect(functools.partial(domain_modes, BATCH, 0, modes))
            _entries_are_the_physics(data, [modes] * BATCH, f"{layout}, {modes}")
    _entries_are_the_physics(_serial(WORKERS), WORKER_ROWS, "serial_env")


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
@pytest.mark.parametrize("layout", list(PROCESSES))
def test_worker_processes_report_the_physics_they_ran(layout: str, fork_start_method):
    _entries_are_the_physics(PROCESSES[layout](WORKERS), WORKER_ROWS, layout)


# ------------------------------------------------------------------------------------------------ seeds repeat
def test_a_run_seeded_then_reset_repeats_whatever_came_before():
    """Nothing seeded at construction: the build-time reset draws from torch's global stream. After
    ``collector.set_seed(5); collector.reset()`` the data depends on the seed alone: on other global streams, after
    batches collected before, and when the same collector is seeded again."""

    def collector() -> Collector:
        return _collector(domain_modes(BATCH, None, "fresh"))

    def seeded_run(running: Collector) -> list[TensorDictBase]:
        running.set_seed(5)
        running.reset()
        batches = iter(running)
        return [next(batches).exclude("collector").clone() for _ in range(2)]

    torch.manual_seed(1)
    first = collector()
    expected = seeded_run(first)
    torch.manual_seed(2)
    second = collector()
    next(iter(second))  # a batch before the seed: interval counters, drawn sets and goals move on
    runs = {"another global stream, a batch before": seeded_run(second), "the first collector again": seeded_run(first)}
    first.shutdown(), second.shutdown()
    for what, run in runs.items():
        for batch, reference in zip(run, expected, strict=True):
            differ = [key for key in reference.keys(True, True) if not torch.equal(batch[key], reference[key])]
            assert not differ, f"{what}: {differ}"


def test_set_seed_keeps_the_running_episodes_physics():
    """A set_seed between steps changes no env's physics; every env's next reset is its first draw of the seed."""
    for modes in DOMAIN_MODES:
        env = domain_modes(BATCH, 0, modes)
        env.rollout(5, pendulum_policy(), break_when_any_done=False)
        running = env.base_env.domain_values(list(FIELDS))
        env.set_seed(SEED)
        now = env.base_env.domain_values(list(FIELDS))
        assert all(torch.equal(now[name], running[name]) for name in FIELDS), modes
        first = env.reset()["domain"].clone()
        env.set_seed(SEED)
        assert (env.reset()["domain"] == first).all(), modes


# ------------------------------------------------------------------------------------------------ shared storage
def _no_shared_storage(probe: StorageProbe, name: str, layout: str) -> None:
    assert not probe.found, f"{name}, {layout}: entries under 'next' share storage: {probe.found[:4]}"


def test_no_entry_shares_storage_with_another_frames():
    """Every feature (every stateful transform of the package, a TaskTransform with groups among them), in
    ``env.rollout`` and then a Collector of the same env."""
    for name, feature in FEATURES.items():
        env = probed(feature.make_env, BATCH, SEED)
        probe = env.transform[-1]
        env.rollout(STEPS, feature.make_policy(), break_when_any_done=False)
        _no_shared_storage(probe, name, "rollout")
        collector = Collector(
            env,
            feature.make_policy(),
            frames_per_batch=BATCH * STEPS,
            total_frames=BATCH * STEPS,
            auto_register_policy_transforms=False,
        )
        for _ in collector:
            pass
        collector.shutdown()
        assert probe._steps == 2 * STEPS
        _no_shared_storage(probe, name, "collector")


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_parallel_env_workers_keep_the_goal_the_task_judged_with(fork_start_method):
    """Shared buffers: a worker copies the step's "next" into the root in place. The task's memory holds the goal
    the policy saw (the root's), not the one drawn for the next step, and no entry shares storage in the workers."""
    feature = FEATURES["goal_command"]
    make = functools.partial(probed, feature.make_env, BATCH // 2, SEED)
    collector = Collector(ParallelEnv(2, make), feature.make_policy(), frames_per_batch=BATCH * STEPS, total_frames=-1)
    batches = iter(collector)
    data = torch.cat([next(batches).clone().reshape(-1, STEPS) for _ in range(2)], -1)
    collector.shutdown()
    assert not data[("next", *ALIASES)].any(), "entries under 'next' share storage in the workers"
    judged = data["next", "task", "state_des"]
    assert torch.equal(judged, data["goal"])
    resampled = (data["next", "goal"] != data["goal"]).any(-1) & ~data["next", "done"].squeeze(-1)
    assert resampled.any()
    # the root memory of a frame inside an episode holds the goal of the previous frame
    inside = data["step_count"][:, 1:].squeeze(-1) > 0
    assert torch.equal(data["task", "state_des"][:, 1:][inside], data["goal"][:, :-1][inside])


# ------------------------------------------------------------------------------------------------ shards
GRID = {
    "mass": torch.linspace(0.5, 1.5, 5, dtype=torch.float64).repeat_interleave(5),
    "length": torch.linspace(0.5, 1.5, 5, dtype=torch.float64).repeat(5),
}


def _grid_env(shard: tuple[int, int] | None, batch: int = 5) -> TransformedEnv:
    params = [UniformDomainParam(name, mean=1.0, halfspan=0.5) for name in GRID]
    randomization = DomainRandomization(params, cycle=GRID, shard=shard)
    return TransformedEnv(PendulumEnv(batch_size=[batch], seed=0), Compose(StepCounter(3), randomization))


def _in_order(values: TensorDictBase | dict) -> list[tuple[float, float]]:
    """The (mass, length) points of ``values``, reset by reset and env by env."""
    return list(zip(values["mass"].reshape(-1).tolist(), values["length"].reshape(-1).tolist(), strict=True))


def test_shards_of_a_grid_cover_every_point_once_per_pass():
    """The documented recipe: one shard per worker (``SerialEnv``/``ParallelEnv`` take a list of constructors); each
    worker takes its rows in turn, and the first pass of every worker's rows is the grid, each point once."""
    for workers, batch in ((5, 5), (4, 1)):  # 25 points: five shards of 5 rows; four shards of 7, 6, 6 and 6
        env = SerialEnv(workers, [functools.partial(_grid_env, (k, workers), batch) for k in range(workers)])
        resets = torch.stack([env.reset()["domain"] for _ in range(8)])  # [reset, worker, env]
        env.close()
        grid, first_pass = _in_order(GRID), []
        for k in range(workers):
            taken = _in_order(resets[:, k])
            size = len(range(k, len(grid), workers))  # the rows k, k + workers, ... of the grid
            first_pass += taken[:size]
            assert taken == (taken[:size] * len(taken))[: len(taken)], f"{workers} workers: shard {k} not in turn"
        assert sorted(first_pass) == sorted(grid), f"{workers} workers"


def test_a_checkpoint_of_another_shard_is_refused_and_changes_nothing():
    source = _grid_env((0, 5))
    source.rollout(4, break_when_any_done=False)
    buffer = io.BytesIO()
    torch.save(source.transform.state_dict(), buffer)
    buffer.seek(0)
    state = torch.load(buffer, weights_only=True)
    target = _grid_env((1, 5))
    target.reset()
    before = {key: value.clone() for key, value in target.transform.state_dict().items() if torch.is_tensor(value)}
    with pytest.raises(ValueError, match=r"shard: saved \(0, 5\), here \(1, 5\)"):
        target.transform.load_state_dict(state)
    after = target.transform.state_dict()
    assert all(torch.equal(value, after[key]) for key, value in before.items())
    same = _grid_env((0, 5))
    same.transform.load_state_dict(state)
    assert torch.equal(same.transform[1].domains.mass, source.transform[1].domains.mass)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"shard": (0, 2)}, ValueError, r"needs cycle=\{name: values\}; got cycle=None"),
        ({"shard": (0, 2), "cycle": 4}, ValueError, "a set drawn with cycle=K is drawn by each worker"),
        ({"shard": (2, 2), "cycle": GRID}, ValueError, r"0 <= index < count, got \(2, 2\)"),
        ({"shard": (0, 26), "cycle": GRID}, ValueError, "splits the 25 given domains into 26 shards"),
        ({"shard": (0, 0), "cycle": GRID}, ValueError, r"shard\[1\] \(the number of shards\) must be a positive"),
        ({"shard": 3, "cycle": GRID}, TypeError, r"shard must be a pair \(index, count\)"),
        ({"shard": (0.0, 2), "cycle": GRID}, TypeError, r"shard\[0\]"),
    ],
)
def test_bad_shards_are_refused(kwargs: dict, error: type, match: str):
    params = [UniformDomainParam(name, mean=1.0, halfspan=0.5) for name in GRID]
    with pytest.raises(error, match=match):
        DomainRandomization(params, **kwargs)
