"""What the report's matplotlib figures share: the legend under the panels, PNG bytes, a data URI
for the self-contained page. Figures are built on an Agg canvas, never pyplot (no global backend
switch; safe in threads and notebooks)."""
from __future__ import annotations

import base64
import io
from typing import Any, Sequence


def png_with_legend_below(fig: Any, ncol: int, legend_height: float) -> bytes:
    """The figure as PNG bytes, with the first panel's legend centred under all panels
    (``legend_height`` inches kept free for it)."""
    handles, labels = fig.axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, legend_height / fig.get_figheight(), 1, 1))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def png_uri(png: bytes) -> str:
    """A ``data:`` URI of PNG bytes, for an ``<img>`` of a page that opens from disk."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def rate_bars(ax: Any, pos: Any, rates: Sequence[Any], width: float, color: str, label: str) -> tuple[Any, Any]:
    """Bars of ``rates`` (``metrics.Rate``: value, low, high; None drawn as a gap) in %, at ``pos``,
    with their Wilson 95 % whiskers. Returns the bar heights and the whiskers' tops (in %)."""
    import numpy as np

    def pct(values: Sequence[float | None]) -> Any:
        return np.array([np.nan if v is None else 100 * v for v in values])

    vals, lo, hi = pct([r.value for r in rates]), pct([r.low for r in rates]), pct([r.high for r in rates])
    ax.bar(pos, vals, width, color=color, edgecolor="black", linewidth=0.5, label=label)
    ax.errorbar(pos, vals, yerr=np.clip(np.vstack([vals - lo, hi - vals]), 0, None), fmt="none",
                ecolor="black", elinewidth=0.8, capsize=3)
    return vals, hi
