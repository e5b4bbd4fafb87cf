"""Defects of issue 47 in the reports, each held: the page's bar legend in the bars' colours, a ``|`` in a
row's name kept in its column (summary.md and report.html), reporting's docstring naming its modules."""
from __future__ import annotations

import re
from pathlib import Path

import rsb_maniskill.reporting as reporting
from rsb_maniskill.reporting.page import BAR_COLORS, build_html
from rsb_maniskill.reporting.summary import results_from_records
from rsb_maniskill.reporting.writer import write_report

PIPE = re.compile(r"(?<!\\)\|")


def _records(policy: str) -> list[dict]:
    out = []
    for i in range(8):
        ok, grasped = i < 3, i < 6
        out.append({"policy": policy, "suite_id": "RSB-Math-4", "seed": i, "instruction_mode": "normal",
                    "grasped_any": grasped, "grasped_correct": ok, "placed_correct": ok, "placed_wrong": False,
                    "success": ok, "first_grasped": (i % 4) if grasped else -1, "target_block": 0, "steps": 50})
    return out


def test_the_bar_legend_has_the_bars_colours(tmp_path):
    page = build_html(_records("p"), tmp_path)
    legend = dict((name.lower(), color) for color, name in
                  re.findall(r'<b style="color:(#[0-9a-f]{6})">(GSR|TSR|nSG)</b>', page))
    assert legend == BAR_COLORS
    bars = set(re.findall(r'<rect[^>]*fill="(#[0-9a-f]{6})"', page))
    assert set(BAR_COLORS.values()) <= bars


def test_a_pipe_in_a_row_name_stays_in_its_column(tmp_path):
    recs = _records("a|b")
    md = write_report(results_from_records(recs), tmp_path, records=recs)["markdown"].read_text()
    tables = re.findall(r"((?:^\|.*\n)+)", md, re.M)
    assert tables and any("a\\|b" in t for t in tables)
    for t in tables:
        widths = {len(PIPE.findall(line)) for line in t.splitlines()}
        assert len(widths) == 1, t  # every line as many columns as the header
    page = build_html(recs, tmp_path)
    assert "<td>a|b</td>" in page
    for table in re.findall(r"<table>(.*?)</table>", page, re.S):
        head = len(re.findall(r"<th>", table.split("</thead>")[0]))
        for row in re.findall(r"<tr[^>]*>(.*?)</tr>", table.split("</thead>")[1]):
            assert row.count("<td>") == head, row


def test_the_reporting_docstring_names_its_modules():
    folder = Path(reporting.__file__).parent
    named = set(re.findall(r"``([a-z_/]+)(?:\.py|/)``", reporting.__doc__))
    modules = {p.stem for p in folder.glob("*.py") if p.stem != "__init__"} | {"sections", "templates"}
    assert modules <= named, modules - named
    assert all((folder / f"{n}.py").exists() or (folder / n).is_dir() for n in named), named
