"""What the report's matplotlib figures share: the legend under the panels, PNG bytes, a data URI
for the self-contained page. Figures are built on an Agg canvas, never pyplot (no global backend
switch; safe in threads and notebooks)."""
from __future__ import annotations

import base64
import io
from typing import Any


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
