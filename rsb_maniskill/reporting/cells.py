"""How a number is written in the reports: percentages, intervals, changes, Markdown tables.

Every table of ``summary.md``, ``report.html`` and ``rsb report --compare`` writes its cells with
these, so a rate reads the same everywhere: ``12.5`` in a table whose header says %, ``12.5 [3.5,
36.0]`` with its Wilson 95 % interval, ``+4.2`` for a change in points, ``n/a`` when undefined.
"""
from __future__ import annotations

import re
from typing import Any, Sequence

NA = "n/a"  # an undefined rate (nSG without a grasp, a share of nothing)


def pct(x: float | None, digits: int = 1, unit: str = "") -> str:
    """A fraction as a percentage: ``0.125`` -> ``"12.5"`` (``unit="%"``: ``"12.5%"``)."""
    return NA if x is None else f"{100.0 * x:.{digits}f}{unit}"


def ci(value: float | None, low: float | None, high: float | None) -> str:
    """A rate with its interval in percent: ``"12.5 [3.5, 36.0]"``."""
    return NA if value is None else f"{pct(value)} [{pct(low)}, {pct(high)}]"


def rate_cell(rate: Any) -> str:
    """:func:`ci` of a ``metrics.Rate`` (anything with ``value``, ``low`` and ``high``)."""
    return ci(rate.value, rate.low, rate.high)


def delta(a: float | None, b: float | None) -> str:
    """``a - b`` in percentage points, signed: ``"+4.2"``."""
    return NA if a is None or b is None else f"{100 * (a - b):+.1f}"


def cell(text: str) -> str:
    """A table cell's text with its pipes escaped (``\\|``), so a row label such as ``--name a|b``
    stays in its column (a pipe already escaped stays as it is)."""
    return re.sub(r"(?<!\\)\|", r"\\|", str(text))


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown pipe table: the first column left-aligned, the others centred; pipes in cells escaped."""
    lines = ["| " + " | ".join(map(cell, header)) + " |",
             "|" + "|".join(["---"] + [":---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join(map(cell, r)) + " |" for r in rows]
    return "\n".join(lines)


NONE_AT_N = "none at this n"  # a detectable difference where the test cannot reach its power at any difference


def p_value(p: float | None, alpha: float = 0.05) -> str:
    """A p-value beside its mark: 3 decimals, more where rounding would carry it to the other side of
    ``alpha`` or onto it (``0.0498 *``, ``0.0501``: never ``0.050 *``); ``<0.001`` below 0.001."""
    if p is None:
        return NA
    if p < 0.001 <= alpha:
        return "<0.001"
    for digits in range(3, 10):
        text = f"{p:.{digits}f}"
        shown = float(text)
        if (shown < alpha) == (p < alpha) and (shown != alpha or p == alpha):
            return text
    return f"{p:.3e}"


def points(x: float | None, undefined: str = NA) -> str:
    """A detectable difference in points, ``"±8.4"``; ``undefined`` where the rate is not defined,
    :data:`NONE_AT_N` is the caller's for a rate whose test cannot detect any difference."""
    return undefined if x is None else f"\u00b1{100 * x:.1f}"
