"""The page of ``rsb report``: one self-contained HTML page to browse an evaluation.

The page holds the paper tables (the same Markdown as ``summary.md``), per-suite GSR / TSR / nSG
bars with their Wilson intervals, the error analysis (per suite, and Table 7 pooled), the
per-category and bias tables with their charts, and a filterable grid of episodes (policy, suite,
instruction mode, outcome) whose cards show the episode's categories, the instruction (a button
shows a cut one whole), the correct and the grasped candidate, and the first and last frames of the
episode's video when one was recorded (a click opens a frame at full resolution with the whole
instruction; the video plays from ``videos/``). Styles, script, data and frames are inline: it
opens from disk, with no server and no network. Everything is computed from ``episodes.jsonl`` with the functions
of ``metrics.py`` and ``summary.py``, so the page and the summary files always agree; the line under
the title names the benchmark version (records of two never share a page) and the code.

Here the page's data is computed; its markup, styles and script are the Jinja templates of
``templates/`` (``report.html.j2`` includes ``report.css`` and ``report.js``, and draws the bias
charts with the macro of ``bias_chart.html.j2``), rendered with
autoescape: the fragments built here (SVG bars, tables from Markdown, the JSON data) are Markup.
``writer.write_html_report`` writes the file.
"""
from __future__ import annotations

import base64
import html
import json
import math
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from markupsafe import Markup

from rsb_maniskill.evaluation.metrics import OUTCOMES, SuiteMetrics, average, outcome, suite_order
from rsb_maniskill.evaluation.records import CATEGORIES_FIELD, EVAL_INSTRUCTION_MODES, dedupe, one_version, record_row
from rsb_maniskill.evaluation.store import read_manifest
from rsb_maniskill.reporting import sections
from rsb_maniskill.reporting.blocks import to_html
from rsb_maniskill.reporting.cells import pct
from rsb_maniskill.reporting.summary import ERRORS_HEADING, results_from_records, suite_columns, summary_blocks

TEMPLATES = "reporting/templates"  # package data of rsb_maniskill
PAGE_TEMPLATE = "report.html.j2"
# Video frames are kept at the video's own resolution (ManiSkill's 512 x 512 render camera): the
# cards show them small, a click opens one at full size, where the 10-choice blocks' letters can
# be read. At JPEG quality 75 that is ~20 kB a frame (~55 kB per filmed episode in the page, 3x
# a 240-pixel thumbnail); wider videos are scaled down to FRAME_MAX_WIDTH.
FRAME_MAX_WIDTH = 640
FRAME_QUALITY = 75
OUTCOME_LABELS = {"success": "success", "not_placed": "not placed", "wrong_target": "wrong target",
                  "no_grasp": "no grasp"}
OUTCOME_COLORS = {"success": "#2ca02c", "not_placed": "#e6a100", "wrong_target": "#d62728", "no_grasp": "#8c8c8c"}
BAR_COLORS = {"gsr": "#9ecae1", "tsr": "#2171b5", "nsg": "#fd8d3c"}  # the bars and their legend
# What the page shows about a policy row's settings (run.json), beside its averages.
SETTINGS_SHOWN = ("policy", "policy_kwargs", "obs_mode")
# The error analysis's place among the sections (``Section.page_order``): smaller ones above it.
ERRORS_ORDER = 50


# ---------------------------------------------------------------- episodes
def _candidate(spec: Mapping[str, Any] | None, block: int) -> dict[str, Any] | None:
    """Letter, option text and block name of physical block ``block`` (None when no block)."""
    if block is None or int(block) < 0:
        return None
    block = int(block)
    if not spec:
        return {"letter": "?", "option": "", "block": f"block #{block}"}
    slot = list(spec["block_of_option"]).index(block)
    return {"letter": spec["letters"][slot], "option": str(spec["options"][slot]), "block": spec["block_names"][block]}


def _kinds(record: Mapping[str, Any]) -> list[str]:
    """The record's categories as short card tags: ``["times", "answer 3 digits", "template 21"]``."""
    from rsb_maniskill.semantic import categories as cat

    tag = {cat.STEPS: "{} steps", cat.ANSWER_SIZE: "answer {}"}
    cats = record.get(CATEGORIES_FIELD) or {}
    return [tag.get(d, "{}").format(cat.value_label(d, str(cats[d]))) for d in cat.DIMENSIONS
            if d in cats and d != cat.SUITE_KIND]


def video_thumbnails(path: Path, max_width: int = FRAME_MAX_WIDTH) -> tuple[str, str] | None:
    """First and last frame of a video as JPEG data URIs at the video's resolution (at most
    ``max_width`` wide), or None when it cannot be read."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    first = last = None
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        if first is None:
            first = frame
        last = frame
    cap.release()
    if first is None:
        return None

    def uri(frame: Any) -> str:
        h, w = frame.shape[:2]
        if w > max_width:
            frame = cv2.resize(frame, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, FRAME_QUALITY])
        return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")

    return uri(first), uri(last)


def episode_cards(records: Iterable[Mapping[str, Any]], results_dir: Path) -> list[dict[str, Any]]:
    """One plain dict per episode with what its card shows (thumbnails read from ``videos/``), row
    by row, suite by suite, in seed order (workers write records in the order episodes finish)."""
    records = list(records)
    rows = {label: i for i, label in enumerate(dict.fromkeys(record_row(r) for r in records))}
    suites = {s: i for i, s in enumerate(suite_order({r["suite_id"] for r in records}))}
    cards = []
    for r in sorted(records, key=lambda r: (rows[record_row(r)], suites[r["suite_id"]], int(r["seed"]),
                                            int(r.get("variant") or 0))):
        spec = r.get("episode")
        video = r.get("video")
        thumbs = None
        if video and (results_dir / "videos" / video).exists():
            thumbs = video_thumbnails(results_dir / "videos" / video)
        cards.append({
            "row": record_row(r),
            "policy": str(r.get("policy", "?")),
            "suite": r["suite_id"],
            "mode": r.get("instruction_mode", "normal"),
            "seed": int(r["seed"]),
            "outcome": outcome(r),
            "instruction": r.get("instruction", ""),
            "donor_seed": r.get("donor_seed"),
            "variant": r.get("variant"), "variant_kind": r.get("variant_kind"),  # counterfactual scenes
            "correct": _candidate(spec, r.get("target_block", -1)),
            "grasped": _candidate(spec, r.get("first_grasped", -1)),
            "steps": r.get("steps"),
            "said": r.get("text"),  # a talking policy's text, and the option it states
            "said_chars": r.get("text_chars"),  # its length before the record's cut
            "kinds": _kinds(r),  # what kind of episode (categories), as tags
            "stated": r.get("stated_letter") if "stated_letter" in r else None,
            "video": f"videos/{video}" if thumbs else None,
            "thumbs": list(thumbs) if thumbs else None,
        })
    return cards


# ---------------------------------------------------------------- charts
def bars_svg(row: Mapping[str, SuiteMetrics]) -> str:
    """Grouped bars of GSR, TSR and nSG per suite with Wilson 95% whiskers and the 1/N line on TSR."""
    suites = list(row)
    values = [v for m in row.values() for v in (m.nsg.value, m.nsg.low) if v is not None]
    lo = math.floor(min([0.0] + values) * 4) / 4  # nSG goes down to -1/(N-1): round down to a quarter
    group, bar, left, top, plot_h = 150, 34, 46, 26, 200
    width, height = left + group * len(suites) + 10, top + plot_h + 44

    def y(v: float) -> str:
        return f"{top + (1.0 - v) / (1.0 - lo) * plot_h:.1f}"

    out = [f'<svg class="bars" viewBox="0 0 {width} {height}" width="{width}" height="{height}" role="img">']
    for t in (t / 100 for t in range(int(lo * 100), 101, 25)):
        cls = "grid zero" if t == 0 else "grid"
        out.append(f'<line x1="{left}" x2="{width - 10}" y1="{y(t)}" y2="{y(t)}" class="{cls}"/>'
                   f'<text x="{left - 6}" y="{float(y(t)) + 4:.1f}" class="tick">{100 * t:.0f}</text>')
    for i, s in enumerate(suites):
        m = row[s]
        x0 = left + i * group + (group - 3 * bar - 8) / 2
        for j, key in enumerate(("gsr", "tsr", "nsg")):
            rate, x = getattr(m, key), x0 + j * (bar + 4)
            cx = x + bar / 2
            tip = f"{s} {key.upper()} {pct(rate.value, unit='%')}"
            if rate.value is None:
                out.append(f'<text x="{cx:.1f}" y="{float(y(0)) - 4:.1f}" class="na">n/a'
                           f'<title>{tip} (no grasp)</title></text>')
                continue
            tip += f" [{pct(rate.low, unit='%')}, {pct(rate.high, unit='%')}]"
            y0, y1 = sorted((float(y(0)), float(y(rate.value))))
            out.append(f'<rect x="{x:.1f}" y="{y0:.1f}" width="{bar}" height="{max(y1 - y0, 0.5):.1f}" '
                       f'fill="{BAR_COLORS[key]}"><title>{html.escape(tip)}</title></rect>')
            out.append(f'<path d="M{cx:.1f} {y(rate.low)}V{y(rate.high)}M{cx - 5:.1f} {y(rate.low)}h10'
                       f'M{cx - 5:.1f} {y(rate.high)}h10" class="whisker"/>')
            label_y = min(float(y(rate.high)), float(y(rate.value))) - 4
            out.append(f'<text x="{cx:.1f}" y="{label_y:.1f}" class="val">{100 * rate.value:.0f}</text>')
            if key == "tsr":
                yc = y(1.0 / m.n_choices)
                out.append(f'<line x1="{x - 3:.1f}" x2="{x + bar + 3:.1f}" y1="{yc}" y2="{yc}" class="chance">'
                           f'<title>random selection 1/N = {100 / m.n_choices:.0f}%</title></line>')
        xc = left + i * group + group / 2
        out.append(f'<text x="{xc:.1f}" y="{top + plot_h + 18}" class="suite">{html.escape(s.removeprefix("RSB-"))}'
                   f'</text><text x="{xc:.1f}" y="{top + plot_h + 34}" class="n">n = {m.n_episodes}</text>')
    out.append("</svg>")
    return "".join(out)


# ---------------------------------------------------------------- page
@lru_cache(maxsize=1)
def templates() -> Any:
    """The Jinja environment of reporting's templates (report.html, the leaderboard's index.html;
    jinja2 imported on first use)."""
    from jinja2 import Environment, PackageLoader, select_autoescape

    # keep_trailing_newline: the included CSS and script end with their own newline
    return Environment(loader=PackageLoader("rsb_maniskill", TEMPLATES),
                       autoescape=select_autoescape(("html", "html.j2")), keep_trailing_newline=True)


def _script_json(data: Any) -> Markup:
    # Inside the page's script element, "</" would end it early.
    return Markup(json.dumps(data, ensure_ascii=False, separators=(",", ":")).replace("</", "<\\/"))


def _summary_rows(results: Mapping[str, Mapping[str, SuiteMetrics]], policy_of: Mapping[str, str],
                  runs: Mapping[str, Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per row: its averages, the settings it was run with and its bars."""
    rows = []
    for label, row in results.items():
        a = average(row)
        settings = runs.get(policy_of.get(label, label), {})
        info = ", ".join(f"{k}: {json.dumps(settings[k])}" for k in SETTINGS_SHOWN
                         if settings.get(k) not in (None, {}, ""))
        rows.append({"label": label, "complete": a.complete, "n_suites": len(a.present), "n_over": len(a.suites),
                     "info": info,
                     **{k: pct(getattr(a, k), unit="%") for k in ("gsr", "tsr", "nsg")},
                     "bars": Markup(bars_svg(row))})
    return rows


def _error_rows(results: Mapping[str, Mapping[str, SuiteMetrics]]) -> list[dict[str, Any]]:
    """Per row and suite: the episodes of each outcome, and their shares of the stacked bar (%)."""
    out = []
    for label, row in results.items():
        for s, m in row.items():
            counts = {"success": m.n_success, "not_placed": m.errors.not_placed,
                      "wrong_target": m.errors.wrong_target, "no_grasp": m.errors.no_grasp}
            total = sum(counts.values()) or 1
            widths = {k: f"{100 * counts[k] / total:.2f}" for k in OUTCOMES if counts[k]}
            out.append({"label": label, "suite": s, "n": m.n_episodes, "counts": counts, "widths": widths})
    return out


def default_title(policies: Sequence[str], shown: int = 3) -> str:
    """The page's title without ``--title``: the runs it shows (their ``--name`` or policy), not the
    folder's name (``eval`` says nothing)."""
    more = f" and {len(policies) - shown} more" if len(policies) > shown else ""
    return "RSB evaluation: " + ", ".join(policies[:shown]) + more


def _version_line(records: Sequence[Mapping[str, Any]], results_dir: Path) -> str:
    """The page's benchmark line: the version, and the records' verdict where they are not its episodes."""
    from rsb_maniskill.evaluation.provenance import PINNED
    from rsb_maniskill.reporting.results import run_provenance
    from rsb_maniskill.version import benchmark_label

    found = run_provenance(records, results_dir)  # PINNED kept where no data is at hand to re-check
    version = benchmark_label(one_version(records) or "")
    return version if found.verdict == PINNED and not found.kept else found.text()


def build_html(records: Sequence[Mapping[str, Any]], results_dir: Path, title: str | None = None) -> str:
    """The report page for ``records`` (episode files of ``results_dir`` feed the thumbnails)."""
    from rsb_maniskill.version import code_label

    records = dedupe(records)
    results = results_from_records(records)
    cards = episode_cards(records, results_dir)
    suites = suite_columns(results)
    policies = list(dict.fromkeys(c["policy"] for c in cards))
    modes = [m for m in EVAL_INSTRUCTION_MODES if any(c["mode"] == m for c in cards)]
    filters = [("policy", "Policy", policies, {}), ("suite", "Suite", suites, {}),
               ("mode", "Instruction", modes, {}), ("outcome", "Outcome", list(OUTCOMES), OUTCOME_LABELS)]
    paper = summary_blocks(results)
    errors_at = paper.index(ERRORS_HEADING)  # Table 7 joins #errors
    shown = sorted(sections.SECTIONS, key=lambda s: s.page_order)
    pages = [(s, s.page(records, results_dir)) for s in shown]
    upper = [page for s, page in pages if page and s.page_order < ERRORS_ORDER]
    lower = [page for s, page in pages if page and s.page_order >= ERRORS_ORDER]
    nav = [{"anchor": s.anchor, "label": s.nav} for s in shown if s.nav]
    return templates().get_template(PAGE_TEMPLATE).render(
        title=title or default_title(policies),
        version=_version_line(records, results_dir), n_episodes=len(cards), n_rows=len(results),
        n_suites=len(suites), n_videos=sum(1 for c in cards if c["video"]), code=code_label(),
        stamp=datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        rows=_summary_rows(results, {c["row"]: c["policy"] for c in cards}, read_manifest(results_dir)),
        tables=to_html(paper[:errors_at]), pooled_errors=to_html(paper[errors_at:]), errors=_error_rows(results),
        upper=upper, lower=lower, nav=nav,
        outcomes=OUTCOMES, colors=OUTCOME_COLORS, bar_colors=BAR_COLORS, labels=OUTCOME_LABELS,
        filters=[{"key": key, "name": name, "options": options, "labels": labels}
                 for key, name, options, labels in filters],
        episodes=_script_json(cards), style=_script_json({"colors": OUTCOME_COLORS, "labels": OUTCOME_LABELS}),
    )
