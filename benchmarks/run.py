"""Run the torchtasks benchmark suite: ``python benchmarks/run.py [--tiny] [--output DIR]``.

The same as ``torchtasks bench``; the code lives in :mod:`torchtasks.bench` so the installed
command can run it too.
"""

from __future__ import annotations

import sys

from torchtasks.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
