"""The measured figures README.md and docs/ quote come from files the benchmarks recorded
(`benchmarks/results/NAME.json`: command, date, commit, machine with its load), rendered into marked regions
by `scripts/render_figures.py`: a page whose region differs from its file fails here, so a re-recorded
benchmark cannot leave a stale page. The GPU figures live in one table (measured, target or projected, each
with its source) that the other pages link to rather than copy."""
from __future__ import annotations

import datetime as dt
import importlib.util
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
GPU_TABLE = "gpu.md#gpu-figures-measured-and-projected"


@pytest.fixture(scope="module")
def figures():
    spec = importlib.util.spec_from_file_location("render_figures", ROOT / "scripts" / "render_figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def region_text(page: Path, name: str) -> str:
    text = page.read_text(encoding="utf-8")
    m = re.search(rf"<!-- figures: {re.escape(name)}(?: [\w.-]+)? -->\n(.*?)<!-- /figures -->", text, re.S)
    assert m, f"{page.relative_to(ROOT)} has no region of {name}"
    return m.group(1)


def values(page: Path) -> set[str]:
    """The names of the files a page quotes one value of."""
    return set(re.findall(r"<!-- fig: ([\w.-]+) ", page.read_text(encoding="utf-8")))


def outside_regions(text: str) -> str:
    text = re.sub(r"<!-- figures: .*?<!-- /figures -->", "", text, flags=re.S)
    return re.sub(r"<!-- fig: .*?<!-- /fig -->", "", text)


def test_every_marked_region_is_its_recorded_figures(figures):
    stale, errors = [], []
    for page in figures.pages():
        text = page.read_text(encoding="utf-8")
        found: list[str] = []
        if figures.render(text, page, errors=found) != text:
            stale.append(str(page.relative_to(ROOT)))
        errors += [f"{page.relative_to(ROOT)}: {e}" for e in found]
    assert errors == [], "a region names a file, table or figure that is not recorded"
    assert stale == [], (f"{stale}: a region differs from its benchmarks/results file; "
                         "run `python scripts/render_figures.py` and commit the pages with the files")


@pytest.mark.parametrize("path", sorted(RESULTS.glob("*.json")), ids=lambda p: p.stem)
def test_every_recorded_file_names_its_command_date_commit_and_machine(path):
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert doc["name"] == path.stem
    assert doc["command"].strip() and doc["commit"].strip() and isinstance(doc["figures"], dict) and doc["figures"]
    dt.date.fromisoformat(doc["date"][:10])
    machine = doc["machine"]
    assert {"cores", "gpu", "load_1min_start", "load_1min_end"} <= set(machine)
    if doc.get("recorded_from"):  # an earlier run, its figures as reported then: it says so and where it ran
        assert machine["cores"] or machine["gpu"] != "none"
    else:  # measured by a benchmark of this repository: the machine as recorded.py saw it
        assert machine["cores"] >= 1 and machine["load_1min_start"] is not None and doc["command"].startswith("python ")


def test_the_pages_quote_their_measured_figures_from_recorded_files(figures):
    """The figures the README and docs quote as measured: speed tables, the reference policies, start-up, the
    first hour, the per-step cost, the GPU table and the learned baseline, each from its file."""
    readme, docs = ROOT / "README.md", ROOT / "docs"
    for name in ("task_speed", "demo_throughput", "eval_throughput_oracle", "reference_baselines"):
        body = region_text(readme, name)
        assert re.search(r"\d{4}-\d\d-\d\d, commit \w{7}", body), f"{name}: the README's table gives no date and commit"
    assert {"cli_startup", "first_hour", "eval_throughput_random", "eval_throughput_rgb"} <= values(readme)
    assert {"eval_throughput_rgb", "eval_throughput_oracle"} <= values(docs / "scale.md")
    for name in ("episode_cost", "cluster_cpu"):  # from eval_throughput_random and _rgb
        region_text(docs / "scale.md", name)
    region_text(readme, "first_hour")
    region_text(docs / "gpu.md", "gpu_figures")
    region_text(docs / "baselines.md", "dp_baseline")


def test_the_gpu_table_says_what_each_figure_is_and_where_it_comes_from(figures):
    rows = [line.split(" | ") for line in region_text(ROOT / "docs" / "gpu.md", "gpu_figures").splitlines()[2:]]
    assert len(rows) >= 10
    kinds = {row[2].split(" ")[0].rstrip(":,") for row in rows}
    assert kinds <= {"measured", "target", "projected"} and {"measured", "projected"} <= kinds, kinds
    for what, _figure, kind, source in rows:
        if kind.startswith("measured"):  # its file, which names the machine
            assert re.search(r"\]\(\.\./benchmarks/results/\w+\.json\): \d{4}-\d\d-\d\d, commit", source), what
        elif kind.startswith("projected"):  # the arithmetic and the measured row it starts from
            assert "/" in kind and "row" in source, what
        else:
            assert "benchmarks/gpu_check.py" in source, what


def test_other_pages_link_to_the_gpu_table_rather_than_copy_it():
    table = region_text(ROOT / "docs" / "gpu.md", "gpu_figures")
    copied = {f for f in re.findall(r"\b\d,\d{3}\b|\b\d+(?:\.\d)? h\b|\b\d+ min\b", table)}
    for page in (ROOT / "README.md", ROOT / "docs" / "scale.md", ROOT / "docs" / "demos.md"):
        text = page.read_text(encoding="utf-8")
        assert GPU_TABLE.split("#")[1] in text, f"{page.name} does not link the table of GPU figures"
        gpu_sentences = [s for s in re.split(r"(?<=[.:;])\s", outside_regions(text)) if re.search(r"H100|H200", s)]
        found = sorted({f for s in gpu_sentences for f in copied if re.search(rf"(?<![\d,.]){re.escape(f)}", s)})
        assert found == [], f"{page.name} copies GPU figures {found}: link the table instead"


def test_a_region_renders_from_its_file_and_a_missing_one_is_named(figures, tmp_path):
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from recorded import table, write
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    write("probe", {"speed": 12.345, "table": table(["what", "s"], [["a run", "1.5"]])}, command="python probe.py",
          out_dir=tmp_path)
    page = ROOT / "docs" / "probe.md"
    text = ("Fast: <!-- fig: probe speed .1f -->0<!-- /fig --> steps/s.\n\n<!-- figures: probe -->\nold\n"
            "<!-- /figures -->\n")
    out = figures.render(text, page, tmp_path)
    assert out.startswith("Fast: <!-- fig: probe speed .1f -->12.3<!-- /fig --> steps/s.")
    assert "| what | s |\n|---|---:|\n| a run | 1.5 |\n\n*Recorded in [probe.json](" in out
    assert figures.render(out, page, tmp_path) == out  # rendering a rendered page changes nothing
    with pytest.raises(figures.FigureError, match="no recorded file .*missing.json"):
        figures.render("<!-- figures: missing -->\n<!-- /figures -->", page, tmp_path)
    with pytest.raises(figures.FigureError, match="probe.json has no figure 'nope'"):
        figures.render("<!-- fig: probe nope -->1<!-- /fig -->", page, tmp_path)


def test_the_suite_time_is_recorded_from_the_runs_junit_file(figures, tmp_path):
    """scripts/test_durations.py --write: the suite's wall time and counts in test_suite.json (README's
    Tests section quotes them), the durations file beside it."""
    spec = importlib.util.spec_from_file_location("test_durations", ROOT / "scripts" / "test_durations.py")
    durations = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(durations)
    junit = tmp_path / "junit.xml"
    junit.write_text(
        '<testsuites><testsuite name="pytest" tests="3" skipped="1" failures="0" errors="0" time="1410.0">'
        '<testcase classname="tests.acceptance.test_layout" name="test_a" time="30.5"/>'
        '<testcase classname="tests.acceptance.test_layout" name="test_b" time="9.5"/>'
        '<testcase classname="tests.tasks.test_tasks" name="test_gpu" time="0.0"><skipped/></testcase>'
        '</testsuite></testsuites>')
    out = tmp_path / "durations.json"
    assert durations.main([str(junit), "--write", str(out), "--record-to", str(tmp_path), "--commit", "abc1234",
                           "--load", "idle", "--load-start", "1.5", "--load-end", "3.9", "--top", "0"]) == 0
    record = json.loads((tmp_path / "test_suite.json").read_text())
    assert record["figures"] == {"wall_min": 23.5, "test_cpu_min": 0.7, "files": 2, "tests": 3, "skipped": 1,
                                 "failed": 0, "passed": 2}
    assert record["commit"] == "abc1234" and record["machine"]["load_1min_start"] == 1.5
    assert json.loads(out.read_text())["files"]["tests/acceptance/test_layout.py"] == 40.0
    text = "took <!-- fig: test_suite wall_min .1f -->?<!-- /fig --> min, <!-- fig: test_suite passed -->?<!-- /fig -->"
    assert figures.render(text, tmp_path / "README.md", tmp_path) == \
        "took <!-- fig: test_suite wall_min .1f -->23.5<!-- /fig --> min, <!-- fig: test_suite passed -->2<!-- /fig -->"
