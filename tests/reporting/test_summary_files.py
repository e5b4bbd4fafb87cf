"""Summary files: JSON, CSV, Markdown tables in the paper's layout, and the PNG bar chart."""
from __future__ import annotations

import csv
import json
import struct

import pytest

from rsb_maniskill.evaluation.metrics import PAPER_SUITES, Rate
from rsb_maniskill.reporting.cells import ci, delta, markdown_table, pct, rate_cell
from rsb_maniskill.reporting.summary import markdown_tables, plot_summary, results_from_records
from rsb_maniskill.reporting.writer import write_report

from fake_records import records


@pytest.fixture
def results():
    recs = []
    for k, s in enumerate(PAPER_SUITES):  # "good" on all six suites
        recs += records("good", s, 30 + k, 60 - k, 10)  # 100 episodes each
    recs += records("good", "RSB-Direct-4", 95, 5, 0)
    recs += records("clumsy", "RSB-Math-4", 0, 0, 50)  # never grasps: nSG undefined
    recs += records("good", "RSB-Math-4", 25, 75, 0, mode="blank")
    return results_from_records(recs)


def test_results_rows(results):
    assert list(results) == ["good", "clumsy", "good (blank)"]
    assert list(results["good"]) == list(PAPER_SUITES) + ["RSB-Direct-4"]


def test_markdown_layout(results):
    md = markdown_tables(results)
    tsr = md.split("### ")[1]
    header = tsr.splitlines()[2]
    # paper Table 3: suites as columns in the paper's order, the control suite after, then Avg
    cols = [c.strip() for c in header.strip("|").split("|")]
    assert cols == ["Policy"] + list(PAPER_SUITES) + ["RSB-Direct-4", "**Avg\\***"]
    good = next(line for line in tsr.splitlines() if line.startswith("| good |"))
    cells = [c.strip() for c in good.strip("|").split("|")]
    assert cells[1] == "30.0" and cells[7] == "95.0"
    avg_tsr = sum(30 + k for k in range(6)) / 6
    assert cells[-1] == f"**{avg_tsr:.1f}**"  # Direct stays out of Avg
    assert "not all six" in tsr  # partial Avg is flagged (clumsy ran one suite)
    nsg_table = md.split("### ")[2]
    clumsy = next(line for line in nsg_table.splitlines() if line.startswith("| clumsy |"))
    assert "n/a" in clumsy
    assert "RSB-Math-4 GSR | RSB-Math-4 TSR" in md  # Table 6 pairs
    assert "Wrong target after grasp" in md and "Grasped correct block but not placed" in md
    assert "[" in md.split("per suite with Wilson")[1]  # intervals in the detail tables


def test_write_report_files(tmp_path, results):
    paths = write_report(results, tmp_path)
    data = json.loads(paths["json"].read_text())
    good = data["rows"]["good"]
    assert good["avg"]["complete"] is True and good["suites"]["RSB-Math-4"]["tsr"]["value"] == pytest.approx(0.3)
    assert data["rows"]["clumsy"]["suites"]["RSB-Math-4"]["nsg"]["value"] is None
    rows = list(csv.DictReader(paths["csv"].open()))
    math4 = next(r for r in rows if r["row"] == "good" and r["suite_id"] == "RSB-Math-4")
    assert float(math4["gsr"]) == pytest.approx(0.9) and float(math4["tsr_low"]) < 0.3 < float(math4["tsr_high"])
    assert next(r for r in rows if r["row"] == "clumsy" and r["suite_id"] == "RSB-Math-4")["nsg"] == ""
    assert {r["row"] for r in rows if r["suite_id"] == "Avg"} == {"good", "clumsy", "good (blank)"}
    assert paths["markdown"].read_text().startswith("Benchmark: RSB-MS ")  # then the tables
    assert {k for k in paths if k.startswith("png:")} == {"png:good", "png:clumsy", "png:good (blank)"}
    # without records there is nothing to split by category or position: no such section, no file
    assert "categories" not in data and "bias" not in data and not any(k.startswith("csv:") for k in paths)


def test_write_report_with_records_adds_the_why_sections(tmp_path):
    """Records of every row get the per-category (here: none recorded, said so) and bias sections."""
    recs = records("good", "RSB-Math-4", 30, 60, 10)
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    data = json.loads(paths["json"].read_text())
    assert "no per-category table" in data["categories"]["note"] and data["bias"]["rows"]["good"]["RSB-Math-4"]
    md = paths["markdown"].read_text()
    assert md.index("paper Table 7") < md.index("### No per-category tables") < md.index("preferences: verdicts")


def test_plot_is_a_valid_png(tmp_path, results):
    path = plot_summary(results["good"], tmp_path / "chart.png", title="good")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    assert 600 <= width <= 2000 and 300 <= height <= 1200
    assert 10_000 < len(data) < 2_000_000
    assert data.endswith(b"IEND\xaeB`\x82")


def test_cells_read_the_same_in_every_table():
    assert (pct(0.125), pct(0.125, 2), pct(0.125, unit="%"), pct(None)) == ("12.5", "12.50", "12.5%", "n/a")
    assert ci(0.5, 0.25, 0.75) == "50.0 [25.0, 75.0]" and ci(None, None, None) == "n/a"
    assert rate_cell(Rate.of(1, 2)) == "50.0 [9.5, 90.5]" and rate_cell(Rate.of(0, 0)) == "n/a"
    assert (delta(0.5, 0.25), delta(0.25, 0.5), delta(None, 0.5)) == ("+25.0", "-25.0", "n/a")
    assert markdown_table(["A", "B"], [["x", "1"]]) == "| A | B |\n|---|:---:|\n| x | 1 |"


def test_summary_says_the_differences_each_suite_can_detect(tmp_path, results):
    """Issue 59: per suite and metric, the smallest difference a paired comparison on the run's episodes
    detects 4 times in 5, in summary.json and in the per-suite table of summary.md (and the page)."""
    from rsb_maniskill.evaluation.stats import minimum_detectable_difference

    data = json.loads(write_report(results, tmp_path)["json"].read_text())
    math = data["rows"]["good"]["suites"]["RSB-Math-4"]  # 30 successes, 90 grasps of 100
    assert math["detectable_difference"]["tsr"] == minimum_detectable_difference(0.3, 100)
    assert math["detectable_difference"]["gsr"] == minimum_detectable_difference(0.9, 100)
    assert math["detectable_difference"]["nsg"] == pytest.approx(minimum_detectable_difference(30 / 90, 90) / 0.75)
    assert data["rows"]["clumsy"]["suites"]["RSB-Math-4"]["detectable_difference"]["nsg"] is None  # no grasp
    assert "detectable_difference" in data  # what the numbers mean
    md = markdown_tables(results)
    row = next(line for line in md.split("good: per suite")[1].splitlines() if line.startswith("| RSB-Math-4 |"))
    assert row.rstrip(" |").endswith(f"±{100 * minimum_detectable_difference(0.3, 100):.1f}")
    assert "Detectable TSR difference" in md and "`rsb plan`" in md
