"""The ``torchtasks`` command: every subcommand, its help, exit code and outputs.

Most calls go through ``torchtasks.cli.main([...])`` in-process; one subprocess checks that the
module runs as ``python -m torchtasks.cli``. The ``bench`` tests are the benchmark smoke tests: they
check that the suite runs and writes its results, never the timings.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from torchtasks.cli import main

SUBCOMMANDS = ("demo", "list", "check", "bench")
HAS_MUJOCO = importlib.util.find_spec("mujoco") is not None and importlib.util.find_spec("gymnasium") is not None
needs_mujoco = pytest.mark.skipif(not HAS_MUJOCO, reason="needs the mujoco extra (mujoco, gymnasium)")


@pytest.fixture
def keep_threads():
    """Collectors change the number of torch threads of the main process; restore it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def _markdown_rows(text: str) -> list[list[str]]:
    """The cells of every Markdown table row in ``text`` (header and separator rows included)."""
    return [
        [cell.strip() for cell in line.strip().strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith("|")
    ]


# ------------------------------------------------------------------------------------------- help
def test_help_lists_every_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: torchtasks")
    for command in SUBCOMMANDS:
        assert command in out, command


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_subcommand_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: torchtasks {command}")


def test_subcommand_options_in_help(capsys: pytest.CaptureFixture[str]) -> None:
    expected = {
        "demo": ("--quick", "--output", "--seed", "--no-progress"),
        "check": ("ENV_ID", "--seeds", "--steps"),
        "bench": ("--output", "--tiny", "--sections"),
    }
    for command, options in expected.items():
        with pytest.raises(SystemExit):
            main([command, "--help"])
        out = capsys.readouterr().out
        for option in options:
            assert option in out, (command, option)


def test_missing_or_unknown_subcommand_is_an_error(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in ([], ["frobnicate"]):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        assert "usage: torchtasks" in capsys.readouterr().err


def test_module_entry_point() -> None:
    """``python -m torchtasks.cli --help`` works (the console script calls the same ``main``)."""
    result = subprocess.run(
        [sys.executable, "-m", "torchtasks.cli", "--help"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: torchtasks")


# ------------------------------------------------------------------------------------------- list
def test_list_mentions_every_public_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    listed = {line.split()[0] for line in out.splitlines() if line.startswith("  ")}
    for module_name in ("torchtasks.rewards", "torchtasks.tasks", "torchtasks.predefined"):
        module = importlib.import_module(module_name)
        missing = sorted(set(module.__all__) - listed)
        assert not missing, f"{module_name}: {missing} not listed"
    for title in ("Reward functions", "Tasks", "Factories", "Environments and presets"):
        assert f"\n{title}\n" in out, title


# ------------------------------------------------------------------------------------------- demo
@pytest.mark.slow
def test_demo_quick(tmp_path: Path, capsys: pytest.CaptureFixture[str], keep_threads) -> None:
    start = time.perf_counter()
    code = main(["demo", "--quick", "--no-progress", "--output", str(tmp_path)])
    seconds = time.perf_counter() - start
    assert code == 0
    # the quick demo is meant to take seconds (about 3 s here, most of it collection and the plot)
    assert seconds < 20.0, f"torchtasks demo --quick took {seconds:.1f} s"
    out = capsys.readouterr().out
    table = {row[0]: row[1] for row in _markdown_rows(out) if len(row) == 2}
    assert table["frames"] == "32000"
    assert int(table["successes"]) > 0
    for name in ("frames/s", "episodes ended", "failures", "truncations"):
        assert name in table, name
    for term in ("track", "effort", "final"):
        assert f"mean episode reward: {term}" in table, term
    plot = tmp_path / "torchtasks_demo.png"
    assert table["plot"] == str(plot)
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------------------------------ check
@pytest.mark.mujoco
@needs_mujoco
def test_check_halfcheetah(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "HalfCheetah-v5", "--seeds", "1", "--steps", "50"]) == 0
    rows = _markdown_rows(capsys.readouterr().out)
    header, body = rows[0], rows[2:]
    assert len(body) == 1
    row = dict(zip(header, body[0], strict=True))
    assert row["env"] == "HalfCheetah-v5"
    assert row["steps"] == "50"
    assert row["termination mismatches"] == "0"
    assert row["observation mismatches"] == "0"
    assert float(row["max abs reward diff"]) <= 1e-5


# ------------------------------------------------------------------------------------------ bench
def _check_bench_outputs(folder: Path, section: str) -> dict:
    results = json.loads((folder / "benchmarks.json").read_text())
    markdown = (folder / "benchmarks.md").read_text()
    assert results["tiny"] is True
    assert results.get(section), f"no {section} results"
    assert markdown.startswith("# torchtasks benchmarks")
    assert "Tiny smoke run" in markdown
    return results


def test_bench_tiny_memory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--tiny", "--sections", "memory", "--output", str(tmp_path)]) == 0
    results = _check_bench_outputs(tmp_path, "memory")
    assert set(results) == {"machine", "tiny", "memory"}
    cases = [row["case"] for row in results["memory"]]
    assert cases[:3] == ["T1", "T2", "T3"]
    assert all(isinstance(row["bytes_per_env"], int) and row["bytes_per_env"] > 0 for row in results["memory"])
    markdown = (tmp_path / "benchmarks.md").read_text()
    assert "## Task memory" in markdown
    assert markdown in capsys.readouterr().out  # the same tables are printed


@pytest.mark.slow
def test_bench_tiny_tasks(tmp_path: Path) -> None:
    """One tiny run of the task-evaluation section (eager, compiled, hand-fused and numpy-loop paths)."""
    assert main(["bench", "--tiny", "--sections", "tasks", "--output", str(tmp_path)]) == 0
    results = _check_bench_outputs(tmp_path, "tasks")
    assert "memory" not in results and "collector" not in results
    rows = results["tasks"]
    assert {(row["case"], row["batch"]) for row in rows} >= {
        (case, batch) for case in ("T1", "T2", "T3") for batch in (1, 8)
    }
    for row in rows:
        for path in ("eager", "compiled", "fused", "numpy_loop"):
            assert row["us"][path] > 0, (row["case"], row["batch"], path)
    markdown = (tmp_path / "benchmarks.md").read_text()
    assert re.search(r"^\| T1 \| 1 \|", markdown, flags=re.MULTILINE)
