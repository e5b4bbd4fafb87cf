"""reporting/blocks.py: one structure, two renderers. summary.md's text and report.html's tables come
from the same blocks; each section builds its blocks from its rows, and its HTML never goes through Markdown."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import rsb_maniskill.reporting as reporting
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.reporting import sections
from rsb_maniskill.reporting.blocks import SMALL_MARK, Bullets, Cell, Grid, Heading, Note, Strong, to_html, to_markdown
from rsb_maniskill.reporting.sections.base import Section

# 40 records of `rsb eval` (oracle; blind with counterfactual variants; leftmost and a talking policy, some
# perturbed) and 3 answers of `rsb backbone arithmetic`: every section has rows
DATA = Path(__file__).parent / "data" / "sections"

BLOCKS = [
    Heading("a|b <on> RSB-Math-4"),
    Note("* Avg over some suites; p < 0.05"),
    Grid(["Policy", "n", (Strong("Avg", mark="*"), " GSR")],
         [["a|b", Cell("5", small=True), Strong("12.5")],
          ["x*y & z", "7", ""]]),
    Bullets(("one / two: reason", "three")),
]


def test_to_markdown_writes_the_summary_form():
    assert to_markdown(BLOCKS) == (
        "### a|b <on> RSB-Math-4\n\n"
        "\\* Avg over some suites; p < 0.05\n\n"
        "| Policy | n | **Avg\\*** GSR |\n"
        "|---|:---:|:---:|\n"
        f"| a\\|b | 5{SMALL_MARK} | **12.5** |\n"
        "| x*y & z | 7 |  |\n\n"
        "- one / two: reason\n- three\n")
    assert to_markdown([]) == ""


def test_to_html_writes_the_page_form():
    assert to_html(BLOCKS) == (
        "<h3>a|b &lt;on&gt; RSB-Math-4</h3>\n"
        '<p class="note">* Avg over some suites; p &lt; 0.05</p>\n'
        '<div class="scroll"><table><thead><tr><th>Policy</th><th>n</th><th><strong>Avg</strong>* GSR</th></tr>'
        "</thead><tbody>"
        f'<tr><td>a|b</td><td class="small">5{SMALL_MARK}</td><td><strong>12.5</strong></td></tr>'
        "<tr><td>x*y &amp; z</td><td>7</td><td></td></tr>"
        "</tbody></table></div>\n"
        '<p class="note">- one / two: reason</p>\n<p class="note">- three</p>')
    assert to_html([]) == ""


def test_a_pipe_stays_in_its_column_in_both():
    grid = Grid(["Policy", "TSR"], [["a|b\\|c", "1"]])
    assert to_markdown([grid]).splitlines()[2] == "| a\\|b\\|c | 1 |"  # cells.cell: an escaped pipe stays
    assert "<tr><td>a|b\\|c</td><td>1</td></tr>" in to_html([grid])  # the page shows the name as given


@pytest.fixture(scope="module")
def results_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sections")
    for f in DATA.iterdir():
        shutil.copy(f, out / f.name)
    return out


def test_the_data_calls_for_every_section(results_dir):
    records = read_records(results_dir / "episodes.jsonl")
    assert all(s.compute(records, results_dir) is not None for s in sections.SECTIONS)


@pytest.mark.parametrize("section", sections.SECTIONS, ids=lambda s: s.key)
def test_each_sections_page_comes_from_its_rows_not_its_markdown(section, results_dir, monkeypatch):
    records = read_records(results_dir / "episodes.jsonl")
    table = section.compute(records, results_dir)
    markdown = section.markdown(table)

    def no_markdown(self, table):
        raise AssertionError("the page parsed the Markdown")

    monkeypatch.setattr(type(section), "markdown", no_markdown)
    body = section.html(table)
    assert body and "<table>" in body
    if type(section).blocks is not Section.blocks:  # built from blocks: both outputs are its blocks
        blocks = section.blocks(table)
        assert body == to_html(blocks) and markdown.rstrip("\n") == to_markdown(blocks).rstrip("\n")


def test_no_html_is_parsed_from_markdown_any_more():
    source = "".join(p.read_text(encoding="utf-8") for p in Path(reporting.__file__).parent.rglob("*.py"))
    assert "markdown_to_html" not in source
    assert not hasattr(sections.base, "markdown_to_html")
