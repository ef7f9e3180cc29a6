"""``benchmarks/perturbations.py --quick``: every variant built and measured once (its timings mean nothing)."""

from __future__ import annotations

import importlib.util
import json
import random
import statistics
from pathlib import Path
from typing import Any

import pytest
import torch

from repo_paths import ROOT

pytest.importorskip("mujoco")
pytestmark = pytest.mark.mujoco


def _benchmark() -> Any:
    spec = importlib.util.spec_from_file_location("perturbations_benchmark", ROOT / "benchmarks" / "perturbations.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_quick_run_measures_every_perturbation_against_the_plain_preset(tmp_path: Path) -> None:
    module = _benchmark()
    threads = torch.get_num_threads()
    assert module.main(["--quick", "--output", str(tmp_path)]) == 0
    assert torch.get_num_threads() == threads
    result = json.loads((tmp_path / "results.json").read_text())
    assert list(result["raw"]) == list(module.VARIANTS)
    assert all(len(values) == 1 and values[0] > 0 for values in result["raw"].values())
    assert set(result["ratio_to_plain"]) == set(module.VARIANTS) - {"floor", "plain"}
    # calls per step counted for every collected variant; the perturbations add calls, records alone some
    calls = result["calls_per_step"]
    assert set(calls) == set(module.VARIANTS) - {"floor"} and all(value > 0 for value in calls.values())
    assert calls["all four"] > calls["plain"]
    table = (tmp_path / "results.md").read_text()
    assert f"`python benchmarks/perturbations.py --quick --output {tmp_path}`" in table
    for variant in module.VARIANTS[1:]:
        assert f"| {variant} |" in table
    # each variant's env holds exactly the perturbations it names
    env = module.preset(2, 1, module.PARTS["all four"])
    names = {type(t).__name__ for t in env.transform}
    assert {"ObservationNoise", "Pushes", "DomainRandomization"} <= names
    fields = {name for t in env.transform if type(t).__name__ == "DomainRandomization" for name in t.names}
    assert fields == {"action_delay", "actuator_kp_scale"}
    env.close()
    plain = module.preset(2, 1, module.PARTS["plain"])
    assert not {"ObservationNoise", "Pushes", "DomainRandomization"} & {type(t).__name__ for t in plain.transform}
    assert "action_delay" not in {field.name for field in plain.base_env.domain_fields()}
    # "records alone" carries exactly the entries the four add (keys, shapes, dtypes), and computes nothing
    perturbed, records = (
        module.preset(2, 1, module.PARTS["all four"]),
        module.preset(2, 1, module.PARTS["records alone"]),
    )
    plain_keys = set(plain.observation_spec.keys(True, True))
    added = {k: s for k, s in perturbed.observation_spec.items(True, True) if k not in plain_keys}
    carried = {k: s for k, s in records.observation_spec.items(True, True) if k not in plain_keys}
    assert len(added) >= 6 and carried.keys() == added.keys()
    assert all((carried[k].shape, carried[k].dtype) == (added[k].shape, added[k].dtype) for k in added)
    data = records.rollout(2)
    assert all(not data["next", k].any() for k in added)
    for env in (plain, perturbed, records):
        env.close()


def _instructions_benchmark() -> Any:
    path = ROOT / "benchmarks" / "perturbations_instructions.py"
    spec = importlib.util.spec_from_file_location("perturbations_instructions", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_instruction_count_worker_runs_its_batches_between_the_handshakes(tmp_path: Path) -> None:
    """The process valgrind counts: warm-up, "ready", the counted batches after "go", "done", exit after "end" (the
    counting itself is valgrind's; here a thread plays the parent)."""
    import threading

    module = _instructions_benchmark()
    worker = threading.Thread(target=module.worker, args=("all four", 4, 1, 2, 1, tmp_path))
    worker.start()
    try:
        for signal, answer in (("ready", "go"), ("done", "end")):
            module._wait_for(tmp_path / signal, _Running(worker))
            assert not (tmp_path / "done").exists() or signal == "done"
            (tmp_path / answer).touch()
    finally:
        (tmp_path / "go").touch()
        (tmp_path / "end").touch()
        worker.join()


class _Running:
    """A thread seen as a process (``poll()``: ``None`` while it runs)."""

    def __init__(self, thread: Any) -> None:
        self.thread, self.returncode = thread, None

    def poll(self) -> int | None:
        self.returncode = None if self.thread.is_alive() else 0
        return self.returncode


def test_the_instruction_count_is_read_from_the_callgrind_totals(tmp_path: Path) -> None:
    module = _instructions_benchmark()
    (tmp_path / "out").write_text("events: Ir\nsummary: 0\ntotals: 8259593231\n")
    assert module.totals(tmp_path / "out") == 8259593231
    (tmp_path / "bad").write_text("events: Ir\n")
    with pytest.raises(ValueError, match="has no 'totals:' line"):
        module.totals(tmp_path / "bad")
    with pytest.raises(SystemExit):  # argparse's error: the unknown variant named, the variants listed
        module.main(["--variants", "plain", "everything"])


def test_a_repeat_interleaves_the_variants_batch_by_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every variant runs one batch per round, in an order reshuffled per round, until one has run the seconds."""
    module = _benchmark()
    clock, log = [0.0], []

    class Fake:
        def __init__(self, name: str, seconds: float, frames: int) -> None:
            self.name, self.seconds, self.frames = name, seconds, frames

        def batch(self) -> int:
            log.append(self.name)
            clock[0] += self.seconds
            return self.frames

    monkeypatch.setattr(module.time, "perf_counter", lambda: clock[0])
    built = {"floor": Fake("floor", 0.1, 50), "plain": Fake("plain", 0.4, 100), "slow": Fake("slow", 0.5, 100)}
    fps = module.sliced(built, 1.2, module.random.Random(0))
    # "slow" reaches 1.2 s in its third batch: three rounds, every variant once in each
    assert len(log) == 9 and all(sorted(log[k : k + 3]) == ["floor", "plain", "slow"] for k in (0, 3, 6))
    assert len({tuple(log[k : k + 3]) for k in (0, 3, 6)}) > 1  # the order is shuffled per round
    assert fps == pytest.approx({"floor": 500.0, "plain": 250.0, "slow": 200.0})
    log.clear()
    assert module.sliced(built, 0.0, module.random.Random(0)) == pytest.approx(fps) and len(log) == 3


def test_variants_measures_the_ones_named_beside_the_floor_and_the_plain_preset(tmp_path: Path) -> None:
    module = _benchmark()
    assert module.main(["--quick", "--calls-batches", "0", "--variants", "all four", "--output", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "results.json").read_text())
    assert list(result["raw"]) == ["floor", "plain", "all four"] and list(result["ratio_to_plain"]) == ["all four"]
    assert "| all four |" in (tmp_path / "results.md").read_text()
    with pytest.raises(SystemExit):
        module.main(["--quick", "--variants", "floor", "--output", str(tmp_path)])


def test_the_interval_of_a_median_holds_it_and_narrows_with_more_repeats() -> None:
    module = _benchmark()
    draw = random.Random(1)
    few = [0.9 + draw.gauss(0.0, 0.05) for _ in range(10)]
    many = few * 10
    for ratios in (few, many):
        low, high = module.median_interval(ratios)
        assert min(ratios) <= low <= statistics.median(ratios) <= high <= max(ratios)
        assert module.median_interval(ratios) == (low, high)  # seeded
    (low_few, high_few), (low_many, high_many) = module.median_interval(few), module.median_interval(many)
    assert high_many - low_many < high_few - low_few
    assert module.median_interval([0.9] * 5) == (0.9, 0.9)
