"""The report's sections, one module each (``base.Section``): rows, JSON, Markdown, files and page.

:data:`SECTIONS` is the registry ``writer.py`` and ``page.py`` loop over: every module of this
package with a ``SECTION``, found at import. summary.md and summary.json take them by
``summary_order``, report.html by ``page_order``. Adding a section is adding one module here
(docs/architecture.md, "Adding a report section").
"""
from __future__ import annotations

import importlib
import pkgutil

from rsb_maniskill.reporting.sections.base import Section


def _discover() -> tuple[Section, ...]:
    """The ``SECTION`` of each module of this package, in summary order."""
    found = []
    for info in pkgutil.iter_modules(__path__):
        section = getattr(importlib.import_module(f"{__name__}.{info.name}"), "SECTION", None)
        if isinstance(section, Section):
            found.append(section)
    return tuple(sorted(found, key=lambda s: s.summary_order))


SECTIONS: tuple[Section, ...] = _discover()
