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
        "check": ("ENV_ID", "--seeds", "--steps", "--backend", "--envs"),
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
DEMO_FILES = {"torchtasks_demo.json", "torchtasks_demo.png"}


@pytest.mark.slow
def test_demo_quick(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], keep_threads
) -> None:
    """The quick demo's table and files; run from ``tmp_path`` with ``--output tmp_path/out``: nothing else appears."""
    monkeypatch.chdir(tmp_path)
    output = tmp_path / "out"
    assert main(["demo", "--quick", "--no-progress", "--output", str(output)]) == 0
    out = capsys.readouterr().out
    table = {row[0]: row[1] for row in _markdown_rows(out) if len(row) == 2}
    assert table["frames"] == "64000"
    assert int(table["successes"]) > 0
    for name in ("frames/s", "action noise σ", "episodes ended", "failures", "truncations"):
        assert name in table, name
    for term in ("track", "effort", "final"):
        assert f"mean episode reward: {term}" in table, term
    assert sorted(path.name for path in tmp_path.iterdir()) == ["out"]
    assert {path.name for path in output.iterdir()} == DEMO_FILES
    for name in sorted(DEMO_FILES):
        assert f"wrote {output / name} " in out, name
    assert (output / "torchtasks_demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    metrics = json.loads((output / "torchtasks_demo.json").read_text())
    curves = metrics["curves"]
    assert metrics["summary"]["frames"] == 64000
    assert {len(values) for values in curves.values()} == {40}  # one value per batch of 1 600 frames
    rates = [rate for rate in curves["success_rate"] if rate is not None]
    returns = [value for value in curves["return"] if value is not None]
    # the action noise decays over the run: success rate and return rise (the curves are not flat)
    assert rates and rates[-1] == 1.0 and min(rates) < 0.8
    assert returns[-1] > returns[0] + 100


def test_demo_default_output_is_runs_demo() -> None:
    from torchtasks.cli import DEMO_OUTPUT, _parser

    assert DEMO_OUTPUT == "runs/demo"
    assert _parser().parse_args(["demo"]).output == "runs/demo"
    assert _parser().parse_args(["demo", "--output", "elsewhere"]).output == "elsewhere"


@pytest.mark.slow
def test_demo_writes_only_under_runs_demo(tmp_path: Path) -> None:
    """``torchtasks demo --quick`` run in ``tmp_path`` without ``--output`` writes ``runs/demo/`` and nothing else."""
    result = subprocess.run(
        [sys.executable, "-m", "torchtasks.cli", "demo", "--quick", "--no-progress"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(path.name for path in tmp_path.iterdir()) == ["runs"]
    assert sorted(path.name for path in (tmp_path / "runs").iterdir()) == ["demo"]
    assert {path.name for path in (tmp_path / "runs" / "demo").iterdir()} == DEMO_FILES
    assert f"wrote {Path('runs/demo/torchtasks_demo.png')} (plot)" in result.stdout


def test_demo_without_matplotlib(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, keep_threads) -> None:
    """Without matplotlib the demo writes its JSON curves and says how to get the plot."""
    from torchtasks.demo import run_demo

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    result = run_demo(total_frames=640, num_envs=8, frames_per_batch=320, output_dir=tmp_path / "demo", progress=False)
    assert result.plot_path is None
    assert result.plot_note is not None and "pip install 'torchtasks[plot]'" in result.plot_note
    assert result.metrics_path == tmp_path / "demo" / "torchtasks_demo.json"
    assert [path.name for path in (tmp_path / "demo").iterdir()] == ["torchtasks_demo.json"]
    assert json.loads(result.metrics_path.read_text())["curves"]["frames"] == [320, 640]


# ----------------------------------------------------------------------- base install, extras
OPTIONAL_MODULES = ("gymnasium", "mujoco", "matplotlib", "ray")
CORE_IMPORT = (
    "import torchtasks, torchtasks.spaces, torchtasks.rewards, torchtasks.tasks, torchtasks.predefined, "
    "torchtasks.transforms, torchtasks.envs, torchtasks.cli"
)


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return result


def test_core_import_does_not_import_optional_modules(tmp_path: Path) -> None:
    """The core and ``torchtasks list`` import neither gymnasium nor matplotlib, even where they are installed.

    (mujoco and ray are imported by torchrl itself wherever they are installed, so they are blocked in
    ``test_core_and_list_without_the_extras`` and checked absent in ``.ci/check_base_install.sh``.)
    """
    code = f"""
import sys
{CORE_IMPORT}
from torchtasks.cli import main
main(["list"])
print("IMPORTED", sorted(name for name in ("gymnasium", "matplotlib") if name in sys.modules))
"""
    out = _python(code, tmp_path).stdout
    assert out.splitlines()[-1] == "IMPORTED []"
    assert "HalfCheetah-v5" in out  # the MuJoCo presets are listed by name all the same


def test_core_and_list_without_the_extras(tmp_path: Path) -> None:
    """With gymnasium, mujoco, matplotlib and ray absent (``sys.modules[name] = None``), the core imports,
    ``torchtasks list`` lists the MuJoCo presets and names the extra, and a preset's error names the extra."""
    code = f"""
import sys
for name in {OPTIONAL_MODULES!r}:
    sys.modules[name] = None
{CORE_IMPORT}
from torchtasks.cli import main
assert main(["list"]) == 0
try:
    torchtasks.envs.gymnasium_env
except ModuleNotFoundError as error:
    print("ERROR", error)
try:
    import torchtasks.envs.locomotion
except ModuleNotFoundError as error:
    print("ERROR", error)
print("CHECK", main(["check", "HalfCheetah-v5"]))
"""
    result = _python(code, tmp_path)
    out = result.stdout
    listed = {line.split()[0]: line for line in out.splitlines() if line.startswith("  ")}
    for name in ("PendulumEnv", "swing_up_task", "SUPPORTED_ENV_IDS", "gymnasium_env", "locomotion_task"):
        assert name in listed, name
    assert "[needs the 'mujoco' extra]" in listed["gymnasium_env"]
    assert "[needs the 'mujoco' extra]" not in listed["PendulumEnv"]
    assert "HalfCheetah-v5" in listed["SUPPORTED_ENV_IDS"]
    assert "[needs the 'mujoco' extra]: pip install 'torchtasks[mujoco]'" in out
    errors = [line for line in out.splitlines() if line.startswith("ERROR")]
    assert len(errors) == 2
    for line in errors:
        assert "needs the 'mujoco' extra: pip install 'torchtasks[mujoco]'" in line, line
    assert out.splitlines()[-1] == "CHECK 2"
    assert "torchtasks check needs the 'mujoco' extra: pip install 'torchtasks[mujoco]'" in result.stderr


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
    sizes = {row["case"]: row["bytes_per_env"] for row in results["memory"]}
    assert all(isinstance(size, int) for size in sizes.values())
    assert all(sizes[case] > 0 for case in ("T1", "T2", "T3"))
    assert sizes.get("T4", 0) == 0  # the locomotion task reads Gymnasium's x_velocity: no memory
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
