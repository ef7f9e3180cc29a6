"""The one rule that keeps a plot readable after a short run (``--quick``): a series with few points gets markers.

A line through one point draws nothing, and a few points joined by lines hide where the data are. Every plot
of the demo and of the example scripts passes its figure through :func:`mark_short_series` before saving it.
Needs no matplotlib import of its own (it reads the figure's artists).
"""

from __future__ import annotations

import math
from typing import Any

#: a data line with fewer finite points than this is drawn with markers (the full runs' curves have more)
FEW_POINTS = 25

#: the markers' style: small, in the line's colour
MARKER = {"marker": "o", "markersize": 4}


def _finite(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def needs_markers(xs: Any, ys: Any) -> bool:
    """Whether a line through ``(xs, ys)`` needs markers to be seen: it has at least one finite point and either
    fewer than :data:`FEW_POINTS` of them, or a finite point with no finite neighbour (drawn as nothing).

    Example:
        >>> nan = float("nan")
        >>> needs_markers([0.0], [1.0]), needs_markers(range(30), [nan] * 30), needs_markers(range(30), range(30))
        (True, False, False)
        >>> needs_markers(range(30), [nan, 1.0, nan] + list(range(27)))  # one point alone between gaps
        True
    """
    finite = [_finite(x) and _finite(y) for x, y in zip(xs, ys, strict=True)]
    if not any(finite):
        return False
    if sum(finite) < FEW_POINTS:
        return True
    padded = [False, *finite, False]
    return any(padded[i] and not padded[i - 1] and not padded[i + 1] for i in range(1, len(padded) - 1))


def mark_short_series(figure: Any) -> int:
    """Give :data:`MARKER` to every data line of ``figure`` (a matplotlib ``Figure``, twin axes included) that
    :func:`needs_markers` and has none; return how many lines got one. Lines in axes coordinates (``axhline``'s
    reference lines) and lines with a marker of their own are left as they are.

    Example:
        >>> from matplotlib.figure import Figure
        >>> figure = Figure()
        >>> axes = figure.subplots()
        >>> one, many = axes.plot([1.0], [2.0])[0], axes.plot(range(50), range(50))[0]
        >>> limit = axes.axhline(1.0)
        >>> mark_short_series(figure), one.get_marker(), many.get_marker(), limit.get_marker()
        (1, 'o', 'None', 'None')
    """
    marked = 0
    for axes in figure.axes:
        for line in axes.get_lines():
            if line.get_transform() != axes.transData or line.get_marker() not in (None, "", " ", "None", "none"):
                continue
            if needs_markers(line.get_xdata(), line.get_ydata()):
                line.set(**MARKER)
                marked += 1
    return marked
