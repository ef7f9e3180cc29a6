"""What the sim-to-real perturbations cost: the velocity-tracking preset with and without them, interleaved.

``python benchmarks/perturbations.py [--envs 64] [--repeats 15] [--seconds 1.0] [--steps-per-batch 20] [--threads N]
[--calls-batches 20] [--output runs/perturbations_bench] [--variants "all four" ...] [--quick]``

The preset is ``velocity_tracking_env(N)`` (the shipped quadruped, 4 substeps per step, its task, command and
``CatTensors``) in a ``torchrl.collectors.Collector`` with uniform random actions (one torch thread,
``N * --steps-per-batch`` frames per batch). These variants are built once and then measured batch by batch: a
repeat is rounds of one batch of every variant, in an order shuffled per round (seeded), until one variant has run
``--seconds`` (at least one round), so each variant's frames/s in a repeat is taken over the same time window as
every other's and each ratio compares numbers taken under the same machine load (this machine's speed moves by a
third within seconds: blocks of a second per variant, as measured until 2026-12-03, gave per-repeat costs from -2% to
+41% for the same code):

- ``floor``: ``mujoco.batch.Batch.step(nstep=4, stage=mjSTAGE_VEL)`` of the preset's own batch after writing random
  controls into its bound ``ctrl`` rows: the physics alone.
- ``plain``: the preset, no perturbation (``max_action_delay=0``, no perturbation transform).
- ``delay``, ``noise``, ``pushes``, ``gains``: the preset with one perturbation each, as
  :func:`~torchtasks.envs.velocity_tracking_perturbations` builds it (``delay``: ``max_action_delay=1`` and its
  draw per env at reset; ``noise``: ``ObservationNoise`` on the five sensed policy entries; ``pushes``: ``Pushes`` of
  the torso, velocity changes of up to 0.5 m/s every 5 to 10 s per env; ``gains``: ``actuator_kp_scale`` drawn per
  env at reset).
- ``all four``: the four together; ``all four + physics``: with the randomized masses and frictions of the same
  function too (the set the example ``examples/velocity_tracking_ppo.py`` trains its robust policy with);
  ``all four, drawn at startup``: the four with the delay and the gains drawn once per env
  (``velocity_tracking_perturbations(when="startup")``, IsaacLab's startup events) instead of at every reset: what
  the randomization's per-reset draw costs.
- ``all but delay``, ``all but noise``, ``all but pushes``, ``all but gains``: the four with one left out: what each
  costs in the combination (``all four`` minus the row), which need not be its cost alone.
- ``records alone``: the plain preset with a transform that writes, at every reset and step, the entries the four
  perturbations add to the data (the same keys, nesting, shapes and dtypes, read off the ``all four`` preset's
  specs), as constant zeros (``Records``: no computation): what carrying the perturbations' records costs in
  TorchRL's step, reset and collector, the floor of any perturbation that records what it did.

The table reports medians over the repeats of frames/s and of the per-repeat ratio to ``plain`` (the cost of a
perturbation is ``1 - ratio``; beside it a 95% interval of that median, by resampling the repeats) and to ``floor``,
and, beside them, the Python function calls per step of each variant (``cProfile``'s count over ``--calls-batches``
batches after the timed repeats; 0: not counted): a measure of the work outside the physics that does not move with the
machine's speed (it moves only with the number of resets in the batches counted, a few percent). Results:
``<output>/results.json`` (every repeat's numbers, the load average before and after, the versions) and
``<output>/results.md``. ``--quick`` runs every code path in seconds (its timings mean nothing).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import platform
import pstats
import random
import shlex
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import mujoco
import torch
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import Transform, TransformedEnv

from torchtasks.envs import velocity_tracking_env, velocity_tracking_perturbations

sys.path.insert(0, str(Path(__file__).resolve().parent))
from control_suite import Collected, Floor  # the same floor and Collector loop

#: the variants, in the order of the table (measured in an order shuffled per round)
VARIANTS = (
    "floor",
    "plain",
    "delay",
    "noise",
    "pushes",
    "gains",
    "all four",
    "all four + physics",
    "all four, drawn at startup",
    "all but delay",
    "all but noise",
    "all but pushes",
    "all but gains",
    "records alone",
)
#: the perturbations of each variant (keywords of velocity_tracking_perturbations)
PARTS = {
    "plain": {},
    "delay": {"delay": True},
    "noise": {"noise": True},
    "pushes": {"pushes": True},
    "gains": {"gains": True},
    "all four": {"delay": True, "noise": True, "pushes": True, "gains": True},
    "all four + physics": {"delay": True, "noise": True, "pushes": True, "gains": True, "physics": True},
    "all four, drawn at startup": {"delay": True, "noise": True, "pushes": True, "gains": True, "startup": True},
    **{
        f"all but {left_out}": {part: part != left_out for part in ("delay", "noise", "pushes", "gains")}
        for left_out in ("delay", "noise", "pushes", "gains")
    },
    "records alone": {"records": True},
}
#: the action delay's maximum where a variant delays
MAX_DELAY = 1


class Records(Transform):
    """Writes ``specs``' entries (a ``Composite`` of the env's batch) as constant zeros at every reset and step: no
    computation, only the cost of carrying them in TorchRL's step, reset and collector."""

    def __init__(self, specs: Composite) -> None:
        super().__init__()
        self.specs = specs
        # by top-level key: a tensor, or a node with its whole subtree, set in one call (as the transforms do)
        self.zeros = dict(specs.zero().items())

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        for key, spec in self.specs.items(True, True):
            observation_spec[key] = spec.clone()
        return observation_spec

    def _write(self, tensordict: TensorDictBase) -> TensorDictBase:
        for key, zeros in self.zeros.items():
            # a node's shallow copy: the step's data may add to its nodes, never to these
            tensordict.set(key, zeros.copy() if isinstance(zeros, TensorDictBase) else zeros)
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._write(next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._write(tensordict_reset)


def added_records(num_envs: int, num_threads: int) -> Composite:
    """The observation entries the ``all four`` preset has and the plain one has not (their specs)."""
    plain, perturbed = preset(num_envs, num_threads, {}), preset(num_envs, num_threads, PARTS["all four"])
    try:
        before = set(plain.observation_spec.keys(True, True))
        added = Composite(shape=perturbed.batch_size)
        for key, spec in perturbed.observation_spec.items(True, True):
            if key not in before:
                added[key] = spec.clone()
        return added
    finally:
        plain.close()
        perturbed.close()


def preset(num_envs: int, num_threads: int, parts: dict[str, bool]) -> TransformedEnv:
    """``velocity_tracking_env`` with the perturbations ``parts`` switched on (all off: the plain preset)."""
    keywords = {name: parts.get(name, False) for name in ("delay", "noise", "pushes", "gains", "physics")}
    perturbations: list[Transform] = []
    if any(keywords.values()):
        when = "startup" if parts.get("startup") else "reset"
        perturbations = velocity_tracking_perturbations(seed=0, max_action_delay=MAX_DELAY, when=when, **keywords)
    if parts.get("records"):
        perturbations = [Records(added_records(num_envs, num_threads))]
    return velocity_tracking_env(
        num_envs,
        seed=0,
        num_threads=num_threads,
        max_action_delay=MAX_DELAY if keywords["delay"] else 0,
        perturbations=perturbations,
    )


def calls_per_step(measured: Collected, batches: int, steps: int) -> float:
    """The Python function calls (``cProfile``: every call, built-in ones too) per step of ``batches`` batches."""
    profile = cProfile.Profile()
    profile.enable()
    try:
        for _ in range(batches):
            measured.batch()
    finally:
        profile.disable()
    calls = sum(entry[1] for entry in pstats.Stats(profile).stats.values())  # type: ignore[attr-defined]
    return calls / (batches * steps)


def sliced(built: dict[str, Floor | Collected], seconds: float, order: random.Random) -> dict[str, float]:
    """One repeat: rounds of one batch of every variant, in an order shuffled per round by ``order``, until one of
    them has run ``seconds`` (at least one round); the frames/s of each over its batches. The variants share the
    repeat's time window batch by batch, so a change of the machine's speed within it reaches each of them alike."""
    frames = dict.fromkeys(built, 0)
    elapsed = dict.fromkeys(built, 0.0)
    while True:
        variants = list(built)
        order.shuffle(variants)
        for variant in variants:
            start = time.perf_counter()
            frames[variant] += built[variant].batch()
            elapsed[variant] += time.perf_counter() - start
        if max(elapsed.values()) >= seconds:
            return {variant: frames[variant] / elapsed[variant] for variant in built}


def median_interval(ratios: list[float], draws: int = 2000) -> tuple[float, float]:
    """A 95% interval of the median of ``ratios`` (one per repeat): the 2.5th and 97.5th percentiles of the medians
    of ``draws`` resamples with replacement (seeded: the same numbers give the same interval)."""
    resample = random.Random(0)
    medians = sorted(statistics.median(resample.choices(ratios, k=len(ratios))) for _ in range(draws))
    return medians[int(0.025 * draws)], medians[int(0.975 * draws) - 1]


def run(
    num_envs: int,
    repeats: int,
    seconds: float,
    steps: int,
    num_threads: int,
    calls_batches: int = 0,
    variants: tuple[str, ...] = VARIANTS,
) -> dict[str, Any]:
    """The ``variants`` (with the floor and the plain preset) built once, then measured batch by batch in each repeat
    (:func:`sliced`); then their calls per step."""
    load_before = os.getloadavg()
    frames_per_batch = num_envs * steps
    variants = tuple(variant for variant in VARIANTS if variant in {"floor", "plain", *variants})
    built: dict[str, Floor | Collected] = {"floor": Floor(preset(num_envs, num_threads, {}), steps)}
    for variant in variants[1:]:
        built[variant] = Collected(preset(num_envs, num_threads, PARTS[variant]), frames_per_batch)
    raw: dict[str, list[float]] = {variant: [] for variant in variants}
    try:
        for repeat in range(repeats):
            for variant, fps in sliced(built, seconds, random.Random(repeat)).items():
                raw[variant].append(fps)
        calls = {
            variant: calls_per_step(measured, calls_batches, steps)
            for variant, measured in built.items()
            if calls_batches and isinstance(measured, Collected)
        }
    finally:
        for measured in built.values():
            measured.close()
    return {
        "num_envs": num_envs,
        "num_threads": num_threads,
        "repeats": repeats,
        "seconds": seconds,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "raw": raw,
        "calls_per_step": calls,
        "calls_batches": calls_batches,
        "median": {variant: statistics.median(values) for variant, values in raw.items()},
        "ratio_to_plain": {
            variant: statistics.median(v / p for v, p in zip(values, raw["plain"], strict=True))
            for variant, values in raw.items()
            if variant not in ("floor", "plain")
        },
        "ratio_to_plain_interval": {
            variant: median_interval([v / p for v, p in zip(values, raw["plain"], strict=True)])
            for variant, values in raw.items()
            if variant not in ("floor", "plain")
        },
        "ratio_to_floor": {
            variant: statistics.median(v / f for v, f in zip(values, raw["floor"], strict=True))
            for variant, values in raw.items()
            if variant != "floor"
        },
    }


def table(result: dict[str, Any]) -> str:
    """The results as a markdown table."""
    lines = [
        f"{result['date']}, `{result['command']}`:",
        f"x{result['num_envs']} envs, {result['num_threads']} MuJoCo threads, medians of {result['repeats']} "
        f"repeats of batches interleaved one by one for {result['seconds']} s; load average before "
        f"{result['load_average_before'][0]:.2f}, after {result['load_average_after'][0]:.2f}",
        "",
        "| variant | frames/s | vs plain | cost (95% interval) | vs floor | Python calls per step |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    calls, plain_calls = result["calls_per_step"], result["calls_per_step"].get("plain")
    for variant in result["median"]:
        fps = result["median"][variant]
        if variant == "floor":
            lines.append(f"| floor (physics alone) | {fps:,.0f} | | | 1.00 | |")
            continue
        to_plain = result["ratio_to_plain"].get(variant)
        plain = "1.00" if to_plain is None else f"{to_plain:.3f}"
        cost = "" if to_plain is None else f"{100 * (1 - to_plain):+.1f}%"
        if to_plain is not None:
            high, low = result["ratio_to_plain_interval"][variant]
            cost += f" ({100 * (1 - low):+.1f} to {100 * (1 - high):+.1f})"
        counted = ""
        if variant in calls:
            counted = f"{calls[variant]:,.0f}"
            if variant != "plain" and plain_calls:
                counted += f" ({100 * (calls[variant] / plain_calls - 1):+.1f}%)"
        floor = result["ratio_to_floor"][variant]
        lines.append(f"| {variant} | {fps:,.0f} | {plain} | {cost} | {floor:.2f} | {counted} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", type=int, default=64, help="envs of the batch (default 64)")
    parser.add_argument("--repeats", type=int, default=15, help="interleaved repeats (default 15)")
    parser.add_argument("--seconds", type=float, default=1.0, help="seconds per repeat and variant (default 1)")
    parser.add_argument("--steps-per-batch", type=int, default=20, help="steps per Collector batch (default 20)")
    parser.add_argument("--threads", type=int, default=2, help="MuJoCo threads (default 2)")
    parser.add_argument(
        "--calls-batches", type=int, default=20, help="batches over which calls per step are counted (0: none)"
    )
    parser.add_argument("--output", type=Path, default=Path("runs/perturbations_bench"), help="where results go")
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=VARIANTS[2:],
        default=VARIANTS[2:],
        metavar="VARIANT",
        help="the variants besides the floor and the plain preset (default: all)",
    )
    parser.add_argument("--quick", action="store_true", help="every code path in seconds (timings mean nothing)")
    args = parser.parse_args(argv)
    if args.quick:
        args.envs, args.repeats, args.seconds, args.steps_per_batch, args.calls_batches = 4, 1, 0.0, 2, 1
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    started = time.perf_counter()
    try:
        result = run(
            args.envs,
            args.repeats,
            args.seconds,
            args.steps_per_batch,
            args.threads,
            args.calls_batches,
            tuple(args.variants),
        )
    finally:
        torch.set_num_threads(threads)
    result.update(
        command=shlex.join(["python", "benchmarks/perturbations.py", *(sys.argv[1:] if argv is None else argv)]),
        date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        wall_seconds=time.perf_counter() - started,
        versions={"python": platform.python_version(), "torch": torch.__version__, "mujoco": mujoco.__version__},
    )
    args.output.mkdir(parents=True, exist_ok=True)
    if not args.quick and result["ratio_to_plain"].get("all four", 1.0) < 0.9:
        print("note: the four perturbations cost more than 10% in this run", file=sys.stderr)
    (args.output / "results.json").write_text(json.dumps(result, indent=2))
    text = table(result)
    (args.output / "results.md").write_text(text)
    print(text, end="")
    print(f"results: {args.output / 'results.json'}, {args.output / 'results.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
