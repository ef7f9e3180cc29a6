"""Every plot of the demo and the examples stays readable after a short run (``--quick``): each plotting function
is called on small fake results (no training) and every data line with few points must carry markers, since a
line through one point draws nothing. The rule itself is ``torchtasks._plotting.mark_short_series``.
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("matplotlib")

from matplotlib.figure import Figure

from example_runs import EXAMPLES
from torchtasks._plotting import FEW_POINTS, mark_short_series, needs_markers

PATH = object()  # where a plotting function takes its output path, when not last


def _frames(n: int) -> list[int]:
    return [2048 * (i + 1) for i in range(n)]


def _ppo_common(n: int) -> tuple[tuple[Any, ...], int]:
    curve = [
        {"frames": f, "seconds": 0.5 * (i + 1), "eval_success_rate": 0.1, "eval_episode_reward": -3.0}
        for i, f in enumerate(_frames(n))
    ]
    return ({"ppo": {"curve": curve, "target": 0.8}}, PATH, "title"), 4  # success and reward, against frames and time


def _curriculum(n: int) -> tuple[tuple[Any, ...], int]:
    module = importlib.import_module("curriculum_reaching")
    levels = len(module.GOAL_HALF_WIDTHS)
    config = {"total_frames": 10**6, "num_envs": 1, "ramp_frames": 10**6, "target": 0.8, "effort_weight": 0.05}
    first = config["num_envs"] * module.MAX_STEPS  # training success is drawn from one full episode on
    run = {
        "seed": 0,
        "curve": [{"frames": first + f, "eval_success_rate": 0.2} for f in _frames(n)],
        "train_curve": [
            {
                "frames": first + f,
                "train_success_rate": 0.3,
                "level_fractions": [1 / levels] * levels,
                "effort_weight": 0.01,
            }
            for f in _frames(n)
        ],
    }
    experiment = {"variants": {"curriculum": [run]}, "config": config, "eval_envs": 4}
    return (experiment,), 3  # evaluation, training success, effort weight (one row: the run is not longer)


def _goal_reaching(n: int) -> tuple[tuple[Any, ...], int]:
    run = {"curve": [{"frames": f, "eval_success_rate": 0.4} for f in _frames(n)], "frames_to_target": None}
    return ({"variants": {"her": {"runs": [run]}}, "config": {"target": 0.8}},), 1


def _potential_shaping(n: int) -> tuple[tuple[Any, ...], int]:
    curve = [{"frames": f, "eval_success_rate": 0.5, "eval_episode_length": 80.0} for f in _frames(n)]
    mean = {key: [point[key] for point in curve] for key in curve[0]}
    variant = {"runs": [{"seed": 0, "curve": curve}], "mean_curve": mean, "label": "sparse"}
    experiment = {"variants": {"sparse": variant}, "target": 0.8, "eval_envs": 4, "success_threshold": 0.1}
    return (experiment,), 4  # one seed and the mean, success rate and episode length


def _locomotion(n: int) -> tuple[tuple[Any, ...], int]:
    record = {
        "seed": 0,
        "total_seconds": 10.0,
        "curve": [{"frames": f, "seconds": i + 1.0, "train_return": -1.0} for i, f in enumerate(_frames(n))],
        "eval_curve": [{"frames": f, "seconds": i + 1.0, "return_mean": -2.0} for i, f in enumerate(_frames(n))],
        "config": {"num_envs": 64, "rollout_steps": 32},
        "env_id": "HalfCheetah-v5",
    }
    return ([record],), 4  # training and evaluation, against frames and time


def _control_suite(n: int) -> tuple[tuple[Any, ...], int]:
    records = [
        {
            "task": task,
            "seed": 0,
            "total_seconds": 10.0,
            "curve": [{"frames": f, "train_return": 100.0} for f in _frames(n)],
            "eval_curve": [{"frames": f, "return_mean": 200.0} for f in _frames(n)],
            "config": {"num_envs": 64, "rollout_steps": 32},
        }
        for task in ("cheetah-run", "walker-walk")
    ]
    return (records,), 4  # training and evaluation, a panel per task


def _safety(n: int) -> tuple[tuple[Any, ...], int]:
    record = {
        "variant": "lagrangian",
        "seed": 0,
        "method": "PPO-Lagrangian",
        "curve": [{"frames": f, "train_return": 5.0, "train_cost": 30.0, "lambda": 0.1} for f in _frames(n)],
        "config": {"cost_limit": 25.0, "num_envs": 16, "rollout_steps": 128},
    }
    return ([record],), 3  # return, cost, λ


def _demo(n: int) -> tuple[tuple[Any, ...], int]:
    from torchtasks.demo import DemoResult

    curves: dict[str, list[Any]] = {"frames": _frames(n), "noise": [1.0] * n}
    for key in ("return", "success_rate", "episode_track", "episode_final", "episode_effort"):
        ended = n - min(n - 1, 2)  # the first two batches end no episode (None): one point of three, or one alone
        curves[key] = [None] * (n - ended) + [0.5] * ended
    result = DemoResult(frames=n, seconds=1.0, episodes=1, successes=1, failures=0, truncations=0,
                        episode_terms={}, curves=curves)  # fmt: skip
    return (result, Figure), 6  # return, success rate, noise, three terms


PLOTS = {  # (module, function, fake arguments with n points -> (arguments before the path, lines with data))
    "_ppo_common.plot": ("_ppo_common", "plot", _ppo_common),
    "curriculum_reaching.plot": ("curriculum_reaching", "plot", _curriculum),
    "goal_reaching.plot": ("goal_reaching", "plot", _goal_reaching),
    "potential_shaping.plot": ("potential_shaping", "plot", _potential_shaping),
    "train_locomotion_ppo.plot": ("train_locomotion_ppo", "plot", _locomotion),
    "control_suite_ppo.plot": ("control_suite_ppo", "plot", _control_suite),
    "train_safety_ppo_lagrangian.plot": ("train_safety_ppo_lagrangian", "plot", _safety),
    "torchtasks.demo._plot": ("torchtasks.demo", "_plot", _demo),
}
NOT_LINE_PLOTS = {"train_hopper_domain_randomization.py", "train_multi_objective_ppo.py"}  # a heatmap, a scatter
#: plots that draw every data line with a marker of their own, at any length (a few evaluations per run)
MARKED_PLOTS = {"velocity_tracking_ppo.py"}


def _data_lines(figure: Figure) -> list[Any]:
    """The lines in data coordinates with at least one finite point (an axhline's reference line is not one)."""
    return [
        line
        for axes in figure.axes
        for line in axes.get_lines()
        if line.get_transform() == axes.transData
        and any(math.isfinite(x) and math.isfinite(y) for x, y in zip(line.get_xdata(), line.get_ydata(), strict=True))
    ]


def _call(plot: Any, arguments: tuple[Any, ...], path: Path) -> None:
    plot(*(path if argument is PATH else argument for argument in arguments), *(() if PATH in arguments else (path,)))


@pytest.fixture
def saved_figures(monkeypatch: pytest.MonkeyPatch) -> list[Figure]:
    """The figures the plotting functions save (nothing is written)."""
    figures: list[Figure] = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *args, **kwargs: figures.append(self))
    monkeypatch.syspath_prepend(str(EXAMPLES))
    return figures


def test_every_plotting_function_is_checked() -> None:
    """Each example that draws with matplotlib is in PLOTS (or draws no lines, or marks every line itself): a new plot
    gets the check too."""
    drawing = {
        path.name
        for path in EXAMPLES.glob("*.py")
        if any(call in path.read_text(encoding="utf-8") for call in ("savefig(", "save_figure("))
    }
    checked = {f"{module}.py" for module, _, _ in PLOTS.values() if not module.startswith("torchtasks")}
    assert drawing == checked | NOT_LINE_PLOTS | MARKED_PLOTS


@pytest.mark.parametrize("points", [1, 3])
@pytest.mark.parametrize("name", PLOTS)
def test_short_series_are_drawn_with_markers(
    name: str, points: int, saved_figures: list[Figure], tmp_path: Path
) -> None:
    """One or three points per series (a ``--quick`` run): every data line is drawn with a visible marker."""
    module, function, fake = PLOTS[name]
    arguments, expected_lines = fake(points)
    _call(getattr(importlib.import_module(module), function), arguments, tmp_path / "plot.png")
    (figure,) = saved_figures
    lines = _data_lines(figure)
    assert len(lines) >= expected_lines, [line.get_label() for line in lines]
    for line in lines:
        assert line.get_marker() not in (None, "", " ", "None", "none"), f"{name}: {line.get_label()!r} has no marker"
        assert line.get_markersize() > 0


@pytest.mark.parametrize("name", PLOTS)
def test_long_series_keep_their_style(name: str, saved_figures: list[Figure], tmp_path: Path) -> None:
    """A full run's curves (more than FEW_POINTS points) get no markers from the rule."""
    module, function, fake = PLOTS[name]
    arguments, _ = fake(FEW_POINTS + 5)
    _call(getattr(importlib.import_module(module), function), arguments, tmp_path / "plot.png")
    (figure,) = saved_figures
    assert mark_short_series(figure) == 0  # already applied before saving: nothing left to mark
    marked = [line.get_label() for line in _data_lines(figure) if line.get_marker() == "o"]
    assert not marked, f"{name}: long series drawn with the short-series marker: {marked}"


def test_the_rule() -> None:
    """Markers for one point, a few points and a point alone between gaps; none for long lines, reference lines
    (axes coordinates) or lines without a finite point; a line's own marker is kept."""
    nan = math.nan
    figure = Figure()
    axes = figure.subplots()
    twin = axes.twinx()
    one = axes.plot([1.0], [2.0])[0]
    few = twin.plot(range(FEW_POINTS - 1), range(FEW_POINTS - 1))[0]
    long = axes.plot(range(FEW_POINTS), range(FEW_POINTS))[0]
    alone = axes.plot(range(40), [nan, 1.0, nan, *range(37)])[0]
    empty = axes.plot([0.0, 1.0], [nan, nan])[0]
    own = axes.plot([1.0], [1.0], marker="x")[0]
    reference = axes.axhline(0.5)
    assert mark_short_series(figure) == 3
    assert [line.get_marker() for line in (one, few, alone)] == ["o", "o", "o"]
    assert [line.get_marker() for line in (long, empty, reference)] == ["None", "None", "None"]
    assert own.get_marker() == "x"
    assert needs_markers([0.0, 1.0], [nan, 2.0]) and not needs_markers([], [])
