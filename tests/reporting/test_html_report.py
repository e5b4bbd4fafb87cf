"""`rsb report` / report.html: built from a real `rsb eval` run (oracle with a video, blind with
shuffled instructions, random) plus synthetic records covering every outcome, then opened in a
real headless Chromium: no console error, no network, filters change the cards, one error analysis,
the per-category and bias tables and plots rendered, a frame at full resolution in the lightbox, a
long instruction read whole, screenshots."""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.metrics import OUTCOMES, suite_order
from rsb_maniskill.evaluation.records import record_row
from rsb_maniskill.evaluation.store import RecordWriter, read_records
from rsb_maniskill.reporting.blocks import to_html
from rsb_maniskill.reporting.page import build_html, episode_cards
from rsb_maniskill.reporting.summary import ERRORS_HEADING, results_from_records, summary_blocks
from rsb_maniskill.reporting.writer import write_html_report

from cdp_browser import Browser, _chromium, checked_screenshot

SUITE = "RSB-Math-4"
N_SYNTHETIC = 130  # more than one page of cards (120)
LONG = " Read it to the end: the last words say which block to take." * 12  # a long instruction, cut on its card


def _synthetic(records: list[dict]) -> list[dict]:
    """Copies of real records relabelled to cover all four outcomes (not placed is rare in practice)."""
    flags = {"success": dict(success=True, grasped_any=True, grasped_correct=True),
             "not_placed": dict(success=False, grasped_any=True, grasped_correct=True),
             "wrong_target": dict(success=False, grasped_any=True, grasped_correct=False),
             "no_grasp": dict(success=False, grasped_any=False, grasped_correct=False, first_grasped=-1)}
    out = []
    for i in range(N_SYNTHETIC):
        r = dict(records[i % len(records)])
        r.pop("video", None)
        r.update(policy="synthetic", suite_id=SUITE if i % 3 else "RSB-Math-10", seed=20_000_000 + i,
                 instruction_mode="normal", **flags[OUTCOMES[i % 4]])
        if i == 0:
            r["instruction"] += LONG
        out.append(r)
    return out


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "results"
    common = ["--suites", SUITE, "-n", "2", "--out", str(out), "-q"]
    assert main(["eval", "oracle", "--videos", "1", *common]) == 0
    assert main(["eval", "blind", "--instruction", "shuffled", *common]) == 0
    assert main(["eval", "random", *common]) == 0
    with RecordWriter(out / "episodes.jsonl") as w:
        for r in _synthetic(read_records(out / "episodes.jsonl")):
            w.write(r)
    return out


def test_eval_writes_the_report_and_rsb_report_rewrites_it(results, capsys):
    page = results / "report.html"
    assert page.exists()  # written by the last `rsb eval`, before the synthetic records
    assert main(["report", str(results)]) == 0
    assert f"report: {page}" in capsys.readouterr().out
    text = page.read_text()
    assert not re.search(r"https?://", text), "the page must not reference the network"
    data = json.loads(re.search(r'<script id="episode-data" type="application/json">(.*?)</script>', text, re.S)[1])
    records = read_records(results / "episodes.jsonl")
    assert len(data) == len(records) == 6 + N_SYNTHETIC
    assert sum(1 for c in data if c["thumbs"]) == 1 and "oracle_RSB-Math-4_normal_seed" in text
    # the paper tables are summary.md's, and the row of the oracle reads 100.0 in Table 3
    assert main(["report", str(results), "--out", str(results / "copy.html"), "--title", "t"]) == 0
    assert "<title>t</title>" in (results / "copy.html").read_text()
    tsr_table = text.split("paper Table 3")[1].split("</table>")[0]
    assert re.search(r"<td>oracle</td><td>100\.0</td>", tsr_table)
    assert re.search(r"<td>random</td><td>0\.0</td>", tsr_table)


def test_cards_name_the_correct_and_the_grasped_candidate(results):
    records = read_records(results / "episodes.jsonl")
    cards = episode_cards(records, results)
    # row by row, suite by suite, in seed order, whatever order the workers wrote the records in
    shuffled = episode_cards(records[1:] + records[:1], results)
    for row in {c["row"] for c in cards}:
        mine = [(c["suite"], c["seed"]) for c in cards if c["row"] == row]
        assert mine == [(c["suite"], c["seed"]) for c in shuffled if c["row"] == row]
        assert [s for s, _ in mine] == sorted((s for s, _ in mine), key=suite_order(s for s, _ in mine).index)
        assert all(a[1] < b[1] for a, b in zip(mine, mine[1:]) if a[0] == b[0])
    by_episode = {(c["row"], c["suite"], c["seed"]): c for c in cards}
    for r in records:
        c = by_episode[(record_row(r), r["suite_id"], int(r["seed"]))]
        spec = r["episode"]
        assert c["correct"]["letter"] == r["correct_letter"]
        assert c["correct"]["block"] == spec["block_names"][r["target_block"]]
        if r["first_grasped"] < 0:
            assert c["grasped"] is None
        else:
            assert c["grasped"]["block"] == spec["block_names"][r["first_grasped"]]
    real = [c for c in cards if c["policy"] != "synthetic"]
    assert [c["outcome"] for c in real] == ["success"] * 2 + ["wrong_target"] * 2 + ["no_grasp"] * 2
    assert [c["grasped"] == c["correct"] for c in real[:2]] == [True, True]
    assert all(c["donor_seed"] is not None for c in real if c["mode"] == "shuffled")
    first, last = real[0]["thumbs"]
    assert first.startswith("data:image/jpeg;base64,") and first != last
    assert real[0]["video"] == f"videos/{records[0]['video']}"


def test_bad_results_dir(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nowhere")]) == 2
    assert "has no episodes.jsonl" in capsys.readouterr().err
    (tmp_path / "episodes.jsonl").write_text("")
    assert main(["report", str(tmp_path)]) == 2
    assert "holds no episode records" in capsys.readouterr().err
    assert not (tmp_path / "report.html").exists()


def test_the_paper_tables_on_the_page_are_summary_mds_blocks(tmp_path):
    """The page's tables and its pooled Table 7 are the blocks summary.md is written from, split at Table 7."""
    from fake_records import records

    recs = records("a|b", SUITE, 2, 1, 1) + records("blind", SUITE, 1, 2, 1)
    blocks = summary_blocks(results_from_records(recs))
    at = blocks.index(ERRORS_HEADING)
    page = build_html(recs, tmp_path)
    assert to_html(blocks[:at]) in page and to_html(blocks[at:]) in page
    assert "<th><strong>Avg</strong>*</th>" in page and "<td>a|b</td>" in page  # a partial Avg; the pipe kept


def test_page_escapes_plain_strings_and_keeps_its_fragments(results, tmp_path):
    """The template escapes the title; the bars, tables and JSON built in Python arrive as markup."""
    page = write_html_report(results, tmp_path / "p.html", title="<b>R&D</b>").read_text()
    assert "<title>&lt;b&gt;R&amp;D&lt;/b&gt;</title>" in page and "<b>R&D</b>" not in page
    assert page.count('<svg class="bars"') == 4  # one per row: oracle, blind (shuffled), random, synthetic
    assert "<h3>Task Success Rate (TSR, %) (paper Table 3)</h3>" in page
    data = re.search(r'<script id="episode-data" type="application/json">(.*?)</script>', page, re.S)[1]
    assert "&#34;" not in data and "&quot;" not in data and len(json.loads(data)) == 6 + N_SYNTHETIC
    # the page's styles and script are the templates', included whole
    templates = Path(__file__).resolve().parents[2] / "rsb_maniskill/reporting/templates"
    assert (templates / "report.css").read_text() in page and (templates / "report.js").read_text() in page


def test_no_markup_in_python():
    """The page's HTML, CSS and JavaScript live in templates/, not in Python strings."""
    package = Path(__file__).resolve().parents[2] / "rsb_maniskill"
    found = [str(f.relative_to(package)) for f in package.rglob("*.py")
             if re.search(r"<(style|script|html)\b", f.read_text(encoding="utf-8"))]
    assert found == []


# ------------------------------------------------------------ in a real browser
def _select(browser: Browser, name: str, value: str) -> int:
    """Pick ``value`` in the filter ``name`` as a user would; the number of cards shown then."""
    return browser.evaluate(f"""(() => {{
        const s = document.querySelector('select[data-filter="{name}"]');
        s.value = {json.dumps(value)};
        s.dispatchEvent(new Event("change"));
        return document.querySelectorAll("#grid .card").length;
    }})()""")


@pytest.mark.timeout(300)
def test_page_in_headless_chromium(results, tmp_path):
    write_html_report(results)
    records = read_records(results / "episodes.jsonl")
    outcomes = [c["outcome"] for c in episode_cards(records, results)]
    with Browser(_chromium(), width=1400, height=1000) as b:
        b.open((results / "report.html").resolve().as_uri())
        cards = lambda: b.evaluate('document.querySelectorAll("#grid .card").length')  # noqa: E731
        assert cards() == 120 and "(showing 120)" in b.evaluate('document.getElementById("count").textContent')
        b.evaluate('document.getElementById("more").click()')
        assert cards() == len(records)
        per_outcome = {o: _select(b, "outcome", o) for o in OUTCOMES}
        assert per_outcome == {o: outcomes.count(o) for o in OUTCOMES} and all(per_outcome.values())
        _select(b, "outcome", "success")
        assert _select(b, "policy", "oracle") == 2  # both filters at once
        _select(b, "outcome", "")
        assert _select(b, "policy", "blind") == 2
        assert _select(b, "mode", "shuffled") == 2 and _select(b, "mode", "normal") == 0  # blind ran shuffled only
        _select(b, "mode", "")
        _select(b, "policy", "")
        assert _select(b, "suite", "RSB-Math-10") == N_SYNTHETIC // 3 + 1
        assert _select(b, "suite", "") == min(120, len(records))
        # the oracle's video: two decoded thumbnails; its play button swaps in the video, which loads
        assert b.evaluate('[...document.querySelectorAll(".media img")].map(i => i.naturalWidth > 0)') == [True, True]
        b.evaluate('document.querySelector(".card .play").click()')
        state = b.evaluate("""new Promise(done => {
            const v = document.querySelector(".media video");
            const t0 = Date.now();
            (function poll() {
                if (v.readyState >= 1 || v.error || Date.now() - t0 > 20000)
                    done([v.readyState, v.error && v.error.code, v.videoWidth]);
                else setTimeout(poll, 100);
            })();
        })""")
        assert state[0] >= 1 and state[1] is None and state[2] > 0, state
        shot = checked_screenshot(b, tmp_path / "report.png", "RSB_REPORT_SCREENSHOT")
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[1] >= 1300 and img.shape[0] > 3000 and img.std() > 20


@pytest.mark.timeout(300)
def test_sections_lightbox_and_long_text_in_chromium(results, tmp_path):
    """One error analysis; the per-category and bias tables and charts; a click on a thumbnail opens
    the frame at the video's resolution with the whole instruction; a cut instruction reads whole."""
    write_html_report(results)
    shots = os.environ.get("RSB_REPORT_SCREENSHOT_DIR")
    with Browser(_chromium(), width=1400, height=1000) as b:
        b.open((results / "report.html").resolve().as_uri())
        h2 = b.evaluate('[...document.querySelectorAll("h2")].map(h => h.textContent)')
        assert h2.count("Error analysis") == 1 and "Per-category results" in h2
        assert b.evaluate('document.querySelector("#tables").textContent.includes("Error analysis")') is False
        assert "paper Table 7" in b.evaluate('document.querySelector("#errors").textContent')
        # per-category tables: one per row and suite with categories, small cells greyed
        cats = b.evaluate('[...document.querySelectorAll("#categories h3")].map(h => h.textContent)')
        assert "oracle on RSB-Math-4: by category (%)" in cats
        assert "Operator" in b.evaluate('document.querySelector("#categories table").textContent')
        assert b.evaluate('document.querySelectorAll("#categories td.small").length') > 0
        # bias: verdicts and per-axis tables, and charts drawn with a bar per position and the expected line
        assert "verdicts" in b.evaluate('document.querySelector("#bias").textContent')
        charts = b.evaluate("""[...document.querySelectorAll("svg.biaschart")].map(s => {
            const box = s.getBoundingClientRect();
            return [box.width, box.height, s.querySelectorAll("rect").length, s.querySelectorAll(".expected").length];
        })""")
        assert charts and all(w > 0 and h > 0 and bars >= 4 and lines == bars for w, h, bars, lines in charts)
        assert b.evaluate('[...document.querySelectorAll("main img")].every(i => i.complete && i.naturalWidth > 0)')
        if shots:
            b.evaluate('document.getElementById("bias").scrollIntoView()')
            b.screenshot(Path(shots) / "bias.png", full_page=False)
        # the lightbox: the frame at the video's resolution, the whole instruction
        b.evaluate('document.querySelector(".media img").click()')
        state = b.evaluate("""new Promise(done => {
            const img = document.getElementById("lb-img");
            const t0 = Date.now();
            (function poll() {
                if (img.complete && img.naturalWidth || Date.now() - t0 > 10000)
                    done([document.getElementById("lightbox").open, img.naturalWidth,
                          img.getBoundingClientRect().width, document.getElementById("lb-text").textContent]);
                else setTimeout(poll, 50);
            })();
        })""")
        records = read_records(results / "episodes.jsonl")
        filmed = next(r for r in records if r.get("video"))
        assert state[0] is True and state[1] == 512 and state[2] >= 512, state[:3]  # not the card's 140 px
        assert state[3].startswith("instruction: " + filmed["instruction"])
        b.evaluate('document.querySelector("#lightbox button[data-frame=\'1\']").click()')
        assert b.evaluate('document.getElementById("lb-img").src') == episode_cards([filmed], results)[0]["thumbs"][1]
        if shots:
            b.screenshot(Path(shots) / "lightbox.png", full_page=False)
        b.evaluate('document.getElementById("lb-close").click()')
        assert b.evaluate('document.getElementById("lightbox").open') is False
        # a long instruction: cut on its card, a button shows it whole
        long_text = next(r["instruction"] for r in records if r["instruction"].endswith(LONG))
        cut = b.evaluate(f"""(() => {{
            const select = document.querySelector('select[data-filter="policy"]');
            select.value = "synthetic";
            select.dispatchEvent(new Event("change"));
            const long = {json.dumps(long_text)};
            const box = [...document.querySelectorAll(".card .instr")].find(e => e.textContent === long);
            const button = box.nextElementSibling;
            const before = [box.scrollHeight > box.clientHeight + 1, button.hidden];
            button.click();
            return before.concat([box.clientHeight >= box.scrollHeight, button.textContent,
                                  box.getBoundingClientRect().height]);
        }})()""")
        assert cut[:2] == [True, False] and cut[2] is True and cut[3] == "show less" and cut[4] > 200, cut
        fits = b.evaluate("""[...document.querySelectorAll(".card .instr")].filter(e => !e.classList.contains("open"))
            .map(e => [e.scrollHeight > e.clientHeight + 1, e.nextElementSibling.hidden])""")
        assert all(clipped != hidden for clipped, hidden in fits)  # the button exactly under cut texts
        assert b.errors() == []
