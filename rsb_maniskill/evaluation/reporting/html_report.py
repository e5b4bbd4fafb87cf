"""``rsb report RESULTS_DIR``: one self-contained HTML page to browse an evaluation.

The page holds the paper tables (the same Markdown as ``summary.md``), per-suite GSR / TSR / nSG
bars with their Wilson intervals, the error analysis, and a filterable grid of episodes (policy,
suite, instruction mode, outcome) whose cards show the instruction, the correct and the grasped
candidate, and the first and last frames of the episode's video when one was recorded (click to
play it from ``videos/``). Styles, script, data and thumbnails are inline: it opens from disk,
with no server and no network. Everything is computed from ``episodes.jsonl`` with the functions
of ``metrics.py`` and ``summary.py``, so the page and the summary files always agree; the line under
the title names the benchmark version (records of two never share a page) and the code. The
command also writes ``results.json`` and, with ``--compare A B``, prints two runs side by side
(``results.py``).
"""
from __future__ import annotations

import argparse
import base64
import html
import json
import math
import os
import re
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from ..metrics import OUTCOMES, SuiteMetrics, average, outcome
from ..records import RECORDS_FILE, dedupe, one_version, read_manifest, read_records, record_row
from .summary import markdown_tables, results_from_records, suite_columns

REPORT_FILE = "report.html"
THUMB_WIDTH = 240
OUTCOME_LABELS = {"success": "success", "not_placed": "not placed", "wrong_target": "wrong target",
                  "no_grasp": "no grasp"}
OUTCOME_COLORS = {"success": "#2ca02c", "not_placed": "#e6a100", "wrong_target": "#d62728", "no_grasp": "#8c8c8c"}
BAR_COLORS = {"gsr": "#9ecae1", "tsr": "#2171b5", "nsg": "#fd8d3c"}


class ReportError(RuntimeError):
    """The results directory holds nothing to report."""


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


def video_thumbnails(path: Path, width: int = THUMB_WIDTH) -> tuple[str, str] | None:
    """First and last frame of a video as JPEG data URIs, or None when it cannot be read."""
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
        small = cv2.resize(frame, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 80])
        return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")

    return uri(first), uri(last)


def episode_cards(records: Iterable[Mapping[str, Any]], results_dir: Path) -> list[dict[str, Any]]:
    """One plain dict per episode with what its card shows (thumbnails read from ``videos/``)."""
    cards = []
    for r in records:
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
            "correct": _candidate(spec, r.get("target_block", -1)),
            "grasped": _candidate(spec, r.get("first_grasped", -1)),
            "steps": r.get("steps"),
            "said": r.get("text"),  # a talking policy's text, and the option it states
            "stated": r.get("stated_letter") if "stated_letter" in r else None,
            "video": f"videos/{video}" if thumbs else None,
            "thumbs": list(thumbs) if thumbs else None,
        })
    return cards


# ---------------------------------------------------------------- charts
def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}%"


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
            tip = f"{s} {key.upper()} {_pct(rate.value)}"
            if rate.value is None:
                out.append(f'<text x="{cx:.1f}" y="{float(y(0)) - 4:.1f}" class="na">n/a'
                           f'<title>{tip} (no grasp)</title></text>')
                continue
            tip += f" [{_pct(rate.low)}, {_pct(rate.high)}]"
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


def outcome_bar(counts: Mapping[str, int]) -> str:
    """A stacked bar of episode outcomes (shares of all episodes)."""
    total = sum(counts.values()) or 1
    parts = [f'<span style="width:{100 * counts[k] / total:.2f}%;background:{OUTCOME_COLORS[k]}" '
             f'title="{OUTCOME_LABELS[k]}: {counts[k]}"></span>' for k in OUTCOMES if counts.get(k)]
    return f'<div class="stack">{"".join(parts)}</div>'


# ---------------------------------------------------------------- Markdown tables -> HTML
def _inline(text: str) -> str:
    text = html.escape(text.strip()).replace("\\*", "*")
    return re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)


def markdown_to_html(md: str) -> str:
    """The subset ``report.markdown_tables`` writes: ``###`` headings, pipe tables, paragraphs."""
    out, table = [], []

    def flush() -> None:
        if not table:
            return
        rows = [[c for c in line.strip().strip("|").split("|")] for line in table]
        head, body = rows[0], [r for r in rows[2:]]
        out.append('<div class="scroll"><table><thead><tr>' + "".join(f"<th>{_inline(c)}</th>" for c in head)
                   + "</tr></thead><tbody>" + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>"
                                                      for r in body) + "</tbody></table></div>")
        table.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("### "):
            out.append(f"<h3>{_inline(line[4:])}</h3>")
        elif line.strip():
            out.append(f"<p class=\"note\">{_inline(line)}</p>")
    flush()
    return "\n".join(out)


# ---------------------------------------------------------------- page
def _options(values: Sequence[str], labels: Mapping[str, str] | None = None) -> str:
    return "".join(f'<option value="{html.escape(v)}">{html.escape((labels or {}).get(v, v))}</option>' for v in values)


def _script_json(data: Any) -> str:
    # Inside <script>: "</" would end the element early.
    return json.dumps(data, ensure_ascii=False, separators=(",", ":")).replace("</", "<\\/")


def _robustness(records: Sequence[Mapping[str, Any]]) -> str:
    """The robustness section (per axis and level, GSR / TSR / nSG and their change from level 0),
    or nothing when no episode was perturbed."""
    from .robustness import robustness_markdown, robustness_table

    table = robustness_table(records)
    if not table:
        return ""
    return ('<section id="robustness"><h2>Robustness</h2><p class="note">Per axis and level: a GSR drop means '
            'the perturbation breaks the grasp, an nSG drop with GSR intact that it breaks the choice. Level 0 '
            'is the unperturbed run of the same seeds.</p>' + markdown_to_html(robustness_markdown(table))
            + "</section>")


def _reasoning(records: Sequence[Mapping[str, Any]]) -> str:
    """Table 5 (what a talking policy stated against what it grasped), or nothing when no policy talked."""
    from .reasoning import reasoning_markdown, reasoning_table

    table = reasoning_table(records)
    if not table:
        return ""
    return ('<section id="reasoning"><h2>Reasoning following</h2><p class="note">For policies that return '
            'text: of the episodes where a block was grasped and the task failed, did the text state the right '
            'option while the arm took a wrong block (the reasoning-following failure), a wrong option, or '
            'none? In brackets: Wilson 95% intervals.</p>' + markdown_to_html(reasoning_markdown(table))
            + "</section>")


def _gap(records: Sequence[Mapping[str, Any]], results_dir: Path) -> str:
    """The semantic gap section (a backbone's answers beside the policy's actions, ``rsb backbone``),
    or nothing when the directory holds no answers."""
    from ..backbone import BACKBONE_FILE, read_backbone_records
    from .gap import backbone_markdown, gap_markdown, gap_table, plot_gap_uri

    if not (results_dir / BACKBONE_FILE).exists():
        return ""
    answers = read_backbone_records(results_dir / BACKBONE_FILE)
    table = gap_table(records, answers)
    plot = (f'<p><img class="plot" src="{plot_gap_uri(table[0])}" alt="the semantic gap per suite"></p>'
            if table[0] else "")
    return ('<section id="gap"><h2>The semantic gap</h2><p class="note">What the policy\'s backbone answers '
            '(<code>rsb backbone</code>, the same episodes asked as the policy gets them) beside what its arm does. '
            'In brackets: Wilson 95% intervals.</p>' + plot
            + markdown_to_html(backbone_markdown(answers) + "\n" + gap_markdown(table)) + "</section>")


def build_html(records: Sequence[Mapping[str, Any]], results_dir: Path, title: str | None = None) -> str:
    """The report page for ``records`` (episode files of ``results_dir`` feed the thumbnails)."""
    records = dedupe(records)
    results = results_from_records(records)
    cards = episode_cards(records, results_dir)
    suites = suite_columns(results)
    title = title or f"RSB evaluation: {results_dir.resolve().name}"
    runs = read_manifest(results_dir)

    policy_of = {c["row"]: c["policy"] for c in cards}
    summary = []
    for label, row in results.items():
        a = average(row)
        settings = runs.get(policy_of.get(label, label), {})
        info = ", ".join(f"{k}: {html.escape(json.dumps(settings[k]))}" for k in ("policy", "policy_kwargs", "obs_mode")
                         if settings.get(k) not in (None, {}, ""))
        summary.append(
            f'<section class="row"><h3>{html.escape(label)}</h3>'
            f'<p class="note">Avg{"" if a.complete else "*"} over {len(a.present)} suite(s): GSR {_pct(a.gsr)}, '
            f'TSR {_pct(a.tsr)}, nSG {_pct(a.nsg)}{" &middot; " + info if info else ""}</p>{bars_svg(row)}</section>')

    err_rows = []
    for label, row in results.items():
        for s, m in row.items():
            counts = {"success": m.n_success, "not_placed": m.errors.not_placed,
                      "wrong_target": m.errors.wrong_target, "no_grasp": m.errors.no_grasp}
            err_rows.append(f"<tr><td>{html.escape(label)}</td><td>{html.escape(s)}</td><td>{m.n_episodes}</td>"
                            + "".join(f"<td>{counts[k]}</td>" for k in OUTCOMES)
                            + f"<td class=\"stackcell\">{outcome_bar(counts)}</td></tr>")
    legend = "".join(f'<span class="key"><i style="background:{OUTCOME_COLORS[k]}"></i>{OUTCOME_LABELS[k]}</span>'
                     for k in OUTCOMES)

    rows = list(results)
    policies = list(dict.fromkeys(c["policy"] for c in cards))
    modes = [m for m in ("normal", "blank", "shuffled") if any(c["mode"] == m for c in cards)]
    filters = [("policy", "Policy", policies, None), ("suite", "Suite", suites, None),
               ("mode", "Instruction", modes, None), ("outcome", "Outcome", list(OUTCOMES), OUTCOME_LABELS)]
    filter_html = "".join(f'<label>{name} <select data-filter="{key}"><option value="">all</option>'
                          f'{_options(vals, labels)}</select></label>' for key, name, vals, labels in filters)
    n_videos = sum(1 for c in cards if c["video"])
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    from rsb_maniskill.version import benchmark_label, code_label

    code = code_label()
    version = benchmark_label(one_version(records) or "")
    return _PAGE.format(
        title=html.escape(title), css=_CSS, script=_SCRIPT, data=_script_json(cards),
        colors=_script_json({"colors": OUTCOME_COLORS, "labels": OUTCOME_LABELS}),
        meta=f"<b>{html.escape(version)}</b> &middot; {len(cards)} episodes &middot; {len(rows)} row(s) &middot; "
             f"{len(suites)} suite(s) &middot; {n_videos} with video &middot; {html.escape(code)} &middot; "
             f"written {stamp}",
        summary="".join(summary), tables=markdown_to_html(markdown_tables(results)),
        robustness=_robustness(records) + _reasoning(records) + _gap(records, results_dir),
        errors="".join(err_rows), legend=legend, filters=filter_html,
    )


def write_html_report(results_dir: str | os.PathLike, out: str | os.PathLike | None = None,
                      records: Sequence[Mapping[str, Any]] | None = None, title: str | None = None) -> Path:
    """Write ``report.html`` for the episodes of ``results_dir`` (or ``records``); returns its path."""
    results_dir = Path(results_dir)
    if records is None:
        if not (results_dir / RECORDS_FILE).exists():
            raise ReportError(f"{results_dir} has no {RECORDS_FILE}: give the --out directory of an `rsb eval` run")
        records = read_records(results_dir / RECORDS_FILE)
    if not records:
        raise ReportError(f"{results_dir / RECORDS_FILE} holds no episode records yet")
    path = Path(out) if out is not None else results_dir / REPORT_FILE
    page = build_html(records, results_dir, title)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, path)  # a reader never sees half a page
    return path


# ---------------------------------------------------------------- command line
def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "report", help="write report.html and results.json; --compare: two runs side by side",
        description="Writes RESULTS_DIR/report.html (a self-contained page that opens from disk) and "
                    "RESULTS_DIR/results.json from RESULTS_DIR/episodes.jsonl (an `rsb eval` output directory). "
                    "RESULTS_DIR may also be a `vla-eval run` output directory (or its *_aggregate.json) of "
                    "RSBBenchmark: then the paper's tables are printed and written to summary.* beside it too. "
                    "With --compare A B: the two runs' GSR / TSR / nSG per suite side by side, B - A, and whether "
                    "their 95 %% intervals separate (Markdown). Records of two benchmark versions never pool.")
    p.add_argument("results_dir", metavar="RESULTS_DIR", nargs="?")
    p.add_argument("-o", "--out", default=None, help="page to write (default: RESULTS_DIR/report.html)")
    p.add_argument("--title", default=None, help="page title (default: the directory's name)")
    p.add_argument("--compare", nargs=2, metavar=("DIR_A", "DIR_B"), default=None,
                   help="compare two results directories (or directories holding a results.json)")
    p.set_defaults(func=run_report)


def run_report(args: argparse.Namespace) -> int:
    from .results import RESULTS_FILE, compare, load_results, write_results
    from .vla_eval_results import is_vla_eval_results, report_vla_eval

    try:
        if args.compare:
            a, b = args.compare
            print(compare(load_results(a), load_results(b), (a, b)), end="")
            return 0
        if not args.results_dir:
            raise ReportError("give RESULTS_DIR, or --compare DIR_A DIR_B")
        if is_vla_eval_results(args.results_dir):  # a `vla-eval run` of RSBBenchmark: summary.* and results.json
            path = report_vla_eval(args.results_dir, args.out, title=args.title)
            src = Path(args.results_dir)
            results = (src if src.is_dir() else src.parent) / RESULTS_FILE
        else:
            records = read_records(Path(args.results_dir) / RECORDS_FILE)
            path = write_html_report(args.results_dir, args.out, records=records or None, title=args.title)
            results = write_results(args.results_dir, records)
    except (ReportError, ValueError, OSError) as err:
        print(f"rsb report: error: {err}", file=sys.stderr)
        return 2
    print(f"results: {results}\nreport: {path}")
    return 0


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title><style>{css}</style></head>
<body>
<header><h1>{title}</h1><p class="meta">{meta}</p>
<nav><a href="#summary">Summary</a><a href="#tables">Paper tables</a><a href="#errors">Error analysis</a>
<a href="#episodes">Episodes</a></nav></header>
<main>
<section id="summary"><h2>GSR, TSR and nSG per suite</h2>
<p class="note">Bars: <b style="color:#6baed6">GSR</b> (a candidate grasped), <b style="color:#2171b5">TSR</b>
(correct block placed), <b style="color:#fd8d3c">nSG</b> (choice among grasps, 0 = random); whiskers: Wilson 95%
intervals; dashed red: 1/N, the TSR of random selection.</p>
{summary}</section>
<section id="tables"><h2>Paper tables</h2>{tables}</section>{robustness}
<section id="errors"><h2>Error analysis</h2><p class="legend">{legend}</p>
<div class="scroll"><table class="errors"><thead><tr><th>Policy</th><th>Suite</th><th>Episodes</th><th>success</th>
<th>not placed</th><th>wrong target</th><th>no grasp</th><th>outcomes</th></tr></thead>
<tbody>{errors}</tbody></table></div></section>
<section id="episodes"><h2>Episodes</h2>
<div class="filters">{filters}<span id="count" class="count"></span></div>
<div id="grid" class="grid"></div><p class="more"><button id="more" type="button">Show more</button></p>
</section></main>
<script id="episode-data" type="application/json">{data}</script>
<script id="report-style" type="application/json">{colors}</script>
<script>{script}</script>
</body></html>
"""

_CSS = """
:root { --fg: #1d232b; --muted: #5d6875; --line: #dde2e8; --bg: #f6f7f9; --card: #fff; }
* { box-sizing: border-box; }
body { margin: 0; font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: var(--fg);
       background: var(--bg); }
header { background: #1f2d3d; color: #fff; padding: 18px 28px 10px; }
header h1 { margin: 0; font-size: 22px; }
.meta { margin: 4px 0 8px; color: #c9d3de; font-size: 13px; }
nav a { color: #9cc8ff; margin-right: 18px; text-decoration: none; font-size: 13px; }
main { padding: 8px 28px 40px; max-width: 1500px; }
h2 { margin: 26px 0 8px; font-size: 18px; }
h3 { margin: 18px 0 6px; font-size: 15px; }
.note { color: var(--muted); margin: 4px 0 8px; font-size: 13px; }
.scroll { overflow-x: auto; }
table { border-collapse: collapse; background: var(--card); font-size: 13px; margin: 4px 0 10px; }
th, td { border: 1px solid var(--line); padding: 4px 8px; text-align: center; white-space: nowrap; }
th { background: #eef1f5; }
td:first-child, th:first-child { text-align: left; }
.row { background: var(--card); border: 1px solid var(--line); border-radius: 8px; padding: 6px 14px 10px;
       margin: 10px 12px 0 0; display: inline-block; vertical-align: top; }
.row p.note { max-width: 430px; }
svg.bars text { font-size: 10px; text-anchor: middle; fill: #333; }
svg.bars .grid { stroke: #e4e7eb; }
svg.bars .zero { stroke: #888; }
svg.bars .tick { text-anchor: end; fill: #777; }
svg.bars .whisker { stroke: #222; stroke-width: 1.1; fill: none; }
svg.bars .chance { stroke: #d62728; stroke-width: 1.6; stroke-dasharray: 4 3; }
svg.bars .suite { font-size: 12px; font-weight: 600; fill: #111; }
svg.bars .n, svg.bars .na { fill: #888; }
.stack { display: flex; width: 220px; height: 14px; border-radius: 3px; overflow: hidden; background: #eee; }
.stack span { display: block; height: 100%; }
.legend .key { margin-right: 14px; font-size: 13px; }
.key i { display: inline-block; width: 11px; height: 11px; border-radius: 2px; margin-right: 5px;
         vertical-align: -1px; }
.filters { position: sticky; top: 0; z-index: 2; background: var(--bg); padding: 8px 0; display: flex; gap: 16px;
           flex-wrap: wrap; align-items: center; border-bottom: 1px solid var(--line); }
.filters select { font: inherit; padding: 3px 6px; border: 1px solid #b9c2cc; border-radius: 5px; background: #fff; }
.count { color: var(--muted); margin-left: auto; }
.grid { display: grid; grid-template-columns: repeat(auto-fill, minmax(300px, 1fr)); gap: 12px; margin-top: 12px; }
.card { background: var(--card); border: 1px solid var(--line); border-radius: 8px; padding: 10px 12px;
        border-top: 4px solid #999; display: flex; flex-direction: column; gap: 6px; }
.card .top { display: flex; justify-content: space-between; align-items: baseline; gap: 8px; }
.card .id { font-weight: 600; font-size: 13px; }
.badge { font-size: 11px; font-weight: 600; color: #fff; border-radius: 10px; padding: 1px 8px; white-space: nowrap; }
.tags { font-size: 12px; color: var(--muted); }
.instr { font-size: 12.5px; color: #2b3440; display: -webkit-box; -webkit-line-clamp: 5; -webkit-box-orient: vertical;
         overflow: hidden; cursor: pointer; white-space: pre-wrap; }
.instr.open { display: block; }
.instr.said { color: #5b3a8c; font-style: italic; }
img.plot { max-width: 100%; background: #fff; border: 1px solid var(--line); border-radius: 6px; }
.cand { font-size: 12.5px; }
.cand b { display: inline-block; width: 62px; color: var(--muted); font-weight: 600; }
.media { display: flex; gap: 4px; }
.media img { width: 50%; border-radius: 4px; cursor: pointer; border: 1px solid var(--line); }
.media video { width: 100%; border-radius: 4px; }
.novideo { font-size: 11px; color: #9aa3ad; }
.more { text-align: center; }
.more button { font: inherit; padding: 6px 18px; border-radius: 6px; border: 1px solid #b9c2cc; background: #fff;
               cursor: pointer; }
"""

_SCRIPT = r"""
(function () {
  "use strict";
  const episodes = JSON.parse(document.getElementById("episode-data").textContent);
  const style = JSON.parse(document.getElementById("report-style").textContent);
  const grid = document.getElementById("grid"), more = document.getElementById("more");
  const count = document.getElementById("count");
  const selects = Array.from(document.querySelectorAll("select[data-filter]"));
  const PAGE = 120;
  let shown = 0, matching = [];

  function el(tag, cls, text) {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function candidate(label, c) {
    const p = el("div", "cand");
    p.appendChild(el("b", "", label));
    const text = c ? c.letter + " \u00b7 " + c.block + (c.option ? " \u2014 " + c.option : "") : "none";
    p.appendChild(document.createTextNode(text));
    return p;
  }
  function card(ep) {
    const color = style.colors[ep.outcome];
    const c = el("article", "card");
    c.style.borderTopColor = color;
    c.dataset.outcome = ep.outcome;
    const top = el("div", "top");
    top.appendChild(el("span", "id", ep.suite + " \u00b7 seed " + ep.seed));
    const badge = el("span", "badge", style.labels[ep.outcome]);
    badge.style.background = color;
    top.appendChild(badge);
    c.appendChild(top);
    let tags = ep.policy + " \u00b7 " + ep.mode + " instruction";
    if (ep.steps != null) tags += " \u00b7 " + ep.steps + " steps";
    if (ep.donor_seed != null) tags += " \u00b7 text of seed " + ep.donor_seed;
    c.appendChild(el("div", "tags", tags));
    const instr = el("div", "instr", ep.instruction || "(blank instruction)");
    instr.title = "click to expand";
    instr.addEventListener("click", () => instr.classList.toggle("open"));
    c.appendChild(instr);
    c.appendChild(candidate("correct", ep.correct));
    c.appendChild(candidate("grasped", ep.grasped));
    if (ep.said !== null && ep.said !== undefined) {
      const said = el("div", "instr said", "said: " + (ep.said || "(nothing)"));
      said.title = "the policy's text; click to expand";
      said.addEventListener("click", () => said.classList.toggle("open"));
      c.appendChild(said);
      const right = ep.correct && ep.stated === ep.correct.letter;
      const states = el("div", "cand");
      states.appendChild(el("b", "", "states"));
      states.appendChild(document.createTextNode(ep.stated ? ep.stated + (right ? " (right)" : " (wrong)")
                                                           : "no option"));
      c.appendChild(states);
    }
    if (ep.thumbs) {
      const media = el("div", "media");
      ep.thumbs.forEach((src, i) => {
        const img = el("img");
        img.src = src;
        img.alt = (i ? "last" : "first") + " frame";
        img.title = "first / last frame; click to play the video";
        img.addEventListener("click", () => {
          const v = el("video");
          v.src = ep.video; v.controls = true; v.autoplay = true; v.muted = true;
          media.replaceChildren(v);
        });
        media.appendChild(img);
      });
      c.appendChild(media);
    } else {
      c.appendChild(el("div", "novideo", "no video recorded (rsb eval --videos K)"));
    }
    return c;
  }
  function showMore() {
    const frag = document.createDocumentFragment();
    matching.slice(shown, shown + PAGE).forEach(ep => frag.appendChild(card(ep)));
    grid.appendChild(frag);
    shown = Math.min(matching.length, shown + PAGE);
    more.hidden = shown >= matching.length;
    count.textContent = matching.length + " of " + episodes.length + " episodes" +
      (shown < matching.length ? " (showing " + shown + ")" : "");
  }
  function apply() {
    const want = {};
    selects.forEach(s => { if (s.value) want[s.dataset.filter] = s.value; });
    matching = episodes.filter(ep => Object.keys(want).every(k => String(ep[k]) === want[k]));
    grid.replaceChildren();
    shown = 0;
    showMore();
  }
  selects.forEach(s => s.addEventListener("change", apply));
  more.addEventListener("click", showMore);
  apply();
})();
"""
