"""``benchmarks/control_suite.py --quick``: every code path on one small task (its timings mean nothing)."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path
from typing import Any

import pytest
import torch

from repo_paths import ROOT

pytest.importorskip("mujoco")


def _benchmark() -> Any:
    spec = importlib.util.spec_from_file_location("control_suite_benchmark", ROOT / "benchmarks" / "control_suite.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(module: Any, arguments: list[str], output: Path) -> tuple[dict[str, Any], str]:
    threads = torch.get_num_threads()
    assert module.main([*arguments, "--output", str(output)]) == 0
    assert torch.get_num_threads() == threads  # the benchmark's one torch thread is not left behind
    table = (output / "results.md").read_text()
    # the table says when, under which load and with which command it was measured (the docs include it as is)
    assert re.search(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC to \d{4}-\d\d-\d\d \d\d:\d\d UTC, 1-minute load average", table)
    assert f"`python benchmarks/control_suite.py {' '.join(arguments)} --output {output}`" in table, table
    return json.loads((output / "results.json").read_text()), table


def test_quick_run_measures_the_preset_against_its_floor_and_says_why_no_peer(tmp_path: Path) -> None:
    """Without the peer venv, the floor, the env alone, the preset and ``--breakdown``'s layers are measured and the
    peer columns say why not."""
    module = _benchmark()
    missing = tmp_path / "no-venv" / "python"
    results, table = _run(module, ["--quick", "--breakdown", "--peer-python", str(missing)], tmp_path)
    (row,) = results["rows"]
    assert row["task"] == "cartpole-swingup" and row["num_envs"] == 2
    assert list(row["raw"]) == ["floor", "env", *module.LAYERS, "preset", module.NO_PHYSICS]  # the measuring order
    assert all(value > 0 for values in row["raw"].values() for value in values)
    floor = row["raw"]["floor"][0]
    others = {variant: values[0] / floor for variant, values in row["raw"].items() if variant != "floor"}
    assert row["ratio_to_floor"] == others
    assert "| cartpole-swingup × 2 | " in table  # the breakdown table's row
    reason = f"not measured: no peer venv ({missing}, --peer-python, does not exist; `make bench-dmc-venv` builds it)"
    assert results["meta"]["peer_status"] == reason
    assert "| cartpole-swingup | 2 |" in table
    assert table.count(reason) == len(module.DEFAULT_PEERS) + 2  # each peer column, the speed-up and the header line


@pytest.mark.slow
@pytest.mark.multiprocess  # the peer worker and its ParallelEnv's worker processes
@pytest.mark.xdist_group("multiprocess")
def test_quick_run_measures_torchrl_dm_control_peers(tmp_path: Path) -> None:
    """With the peer venv (``make bench-dmc-venv``), every default peer variant is measured in it."""
    module = _benchmark()
    python, reason = module.peer_python(None)
    if python is None:
        pytest.skip(reason)
    results, table = _run(module, ["--quick"], tmp_path)
    (row,) = results["rows"]
    assert set(row["raw"]) == {*module.OURS, *module.DEFAULT_PEERS}
    assert all(value > 0 for values in row["raw"].values() for value in values)
    assert set(row["startup_seconds"]) == {"ours", *module.DEFAULT_PEERS}
    best = max(row["raw"][variant][0] for variant in ("serial", "parallel", "parallel_pipes"))
    assert row["preset_over_best_torchrl_peer"] == row["raw"]["preset"][0] / best
    versions = results["meta"]["peer_versions"]
    assert (versions["mujoco"], versions["dm-control"]) == ("3.17.0", "1.0.50")
    assert results["meta"]["peer_status"] is None and "not measured" not in table
