"""The report sections' registry (reporting/sections/): the writer and the page loop over it, and the
worked example of docs/architecture.md ("Adding a report section") adds a section with that one module."""
from __future__ import annotations

import json
import re
import types
from pathlib import Path

import pytest

from rsb_maniskill.reporting import sections
from rsb_maniskill.reporting.page import build_html
from rsb_maniskill.reporting.sections.base import Section
from rsb_maniskill.reporting.summary import results_from_records
from rsb_maniskill.reporting.writer import write_report

ROOT = Path(__file__).resolve().parents[2]


def _records() -> list[dict]:
    from fake_records import records

    out = records("oracle", "RSB-Math-4", 3, 1, 1) + records("blind", "RSB-Math-4", 1, 2, 2)
    for i, r in enumerate(out):
        r["steps"] = 100 + 10 * i
    return out


def test_the_registry_holds_every_section_once():
    keys = [s.key for s in sections.SECTIONS]
    assert keys == ["robustness", "reasoning_following", "backbone", "categories", "bias", "confusion",
                    "counterfactual"]
    assert len({s.anchor for s in sections.SECTIONS}) == len(keys)
    assert all(isinstance(s, Section) for s in sections.SECTIONS)


def _example_module() -> types.ModuleType:
    doc = (ROOT / "docs/architecture.md").read_text(encoding="utf-8")
    part = doc.split("## Adding a report section", 1)[1]
    code = re.search(r"```python\n(.*?)```", part, re.S)[1]
    module = types.ModuleType("rsb_maniskill.reporting.sections.steps")
    exec(compile(code, "docs/architecture.md", "exec"), module.__dict__)
    return module


def test_the_documented_example_adds_a_section_with_one_module(tmp_path, monkeypatch):
    example = _example_module().SECTION
    monkeypatch.setattr(sections, "SECTIONS", (*sections.SECTIONS, example))
    recs = _records()
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    summary = json.loads(paths["json"].read_text())
    assert list(summary)[-1] == "steps" and summary["steps"]["oracle"]["RSB-Math-4"] == 120  # 100..140
    markdown = paths["markdown"].read_text()
    assert "### Episode length" in markdown and "| oracle | RSB-Math-4 | 5 | 120.0† |" in markdown  # as the docs say
    assert paths["csv:steps"].read_text().startswith("row,suite_id,mean_steps")
    page = build_html(recs, tmp_path)
    assert '<a href="#steps">Steps</a>' in page
    assert re.search(r'<section id="steps"><h2>Episode length</h2>.*?<th>Mean steps</th>', page, re.S)
    # the page's table is rendered from the same blocks, the small cell greyed
    assert "<tr><td>oracle</td><td>RSB-Math-4</td><td>5</td><td class=\"small\">120.0†</td></tr>" in page
    # on the page after the preferences (page_order 80 > bias's 70), before the episodes
    assert page.index('<section id="bias">') < page.index('<section id="steps">') < page.index('id="episodes"')


def test_without_the_example_nothing_of_it_is_written(tmp_path):
    recs = _records()
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    assert "steps" not in json.loads(paths["json"].read_text())
    assert 'id="steps"' not in build_html(recs, tmp_path)


@pytest.mark.parametrize("section", sections.SECTIONS, ids=lambda s: s.key)
def test_each_section_is_absent_or_complete_on_plain_records(section, tmp_path):
    recs = _records()
    table = section.compute(recs, tmp_path)
    page = section.page(recs, tmp_path)
    assert (table is None) == (page is None)
    if page:
        assert page["anchor"] == section.anchor and page["title"] == section.title
