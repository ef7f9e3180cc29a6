"""Plot the eight sigmoids of ``torchtasks.rewards.tolerance`` (the figure of docs/designing_rewards.md).

Run: ``python docs/_scripts/tolerance_kernels.py [--output DIR]`` (default ``runs/tolerance_kernels/``;
the docs use ``--output docs/_static``). Needs matplotlib (the ``plot`` extra).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from torchtasks.rewards import SIGMOIDS, tolerance


def main() -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default="runs/tolerance_kernels", help="folder of tolerance_kernels.png")
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = torch.linspace(-3.0, 3.0, 1201, dtype=torch.float64)
    bounds, margin = (-0.5, 0.5), 1.0
    fig, axes = plt.subplots(2, 4, figsize=(13, 5.5), sharex=True, sharey=True)
    for ax, sigmoid in zip(axes.flat, SIGMOIDS, strict=True):
        for value in (0.1, 0.5):
            y = tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value)
            ax.plot(x.numpy(), y.numpy(), label=f"value_at_margin={value}")
        ax.axvspan(*bounds, color="tab:green", alpha=0.12, lw=0)
        for edge in (bounds[0] - margin, bounds[1] + margin):
            ax.axvline(edge, color="grey", ls=":", lw=1)
        ax.set_title(sigmoid)
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="lower center", fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("x")
    fig.suptitle(
        "tolerance(x, bounds=(-0.5, 0.5), margin=1, sigmoid=...): 1 in the bounds (green), "
        "value_at_margin at the dotted lines"
    )
    fig.tight_layout()
    folder = Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "tolerance_kernels.png"
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main()
