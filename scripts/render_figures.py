"""Render the measured figures the pages quote from the files the benchmarks recorded.

    python scripts/render_figures.py           # rewrite every marked region of README.md and docs/*.md
    python scripts/render_figures.py --check   # exit 1 naming each region that differs from its file

A benchmark writes what it measured to ``benchmarks/results/NAME.json`` (``benchmarks/recorded.py``: the
command, date, commit and machine with its load). A page quotes it in a marked region, so that
re-recording and re-rendering keeps every page true (``tests/acceptance/test_docs_figures.py`` checks it):

- a table: ``<!-- figures: NAME -->`` (or ``<!-- figures: NAME TABLE -->``) ... ``<!-- /figures -->``: the
  table ``figures["table"]`` (or ``figures["tables"][TABLE]``) of NAME.json, then a line naming the file,
  the command, date, commit and machine. NAME may instead be one of this module's RENDERERS (a table
  built from several files, such as ``gpu_figures``).
- a value: ``<!-- fig: NAME KEY FORMAT -->0.52<!-- /fig -->``: ``figures[KEY]`` (KEY a dotted path) formatted
  with FORMAT (a Python format spec: ``.2f``, ``,.0f``; omitted: as written in the file). KEY ``@date``
  gives the date, ``@source`` the short provenance (date, commit, machine).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable

from rsb_maniskill.env_ids import PAPER_SUITES, TASK_MAX_EPISODE_STEPS  # light: no simulator
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PAGES = ("README.md", "docs/*.md")

BLOCK = re.compile(r"(<!-- figures: (?P<name>[\w.-]+)(?: (?P<table>[\w.-]+))? -->\n)(?P<body>.*?)(<!-- /figures -->)",
                   re.S)
INLINE = re.compile(r"(<!-- fig: (?P<name>[\w.-]+) (?P<key>@?[\w.-]+)(?: (?P<fmt>\S+))? -->)(?P<body>[^\n]*?)"
                    r"(<!-- /fig -->)")


class FigureError(ValueError):
    """A marked region names a file, table or key that is not there."""


def pages(root: Path = ROOT) -> list[Path]:
    return sorted(p for pattern in PAGES for p in root.glob(pattern))


def read(name: str, results: Path = RESULTS) -> dict[str, Any]:
    path = results / f"{name}.json"
    if not path.is_file():
        raise FigureError(f"no recorded file {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")
    return json.loads(path.read_text(encoding="utf-8"))


def lookup(record: dict[str, Any], key: str) -> Any:
    value: Any = record["figures"]
    for part in key.split("."):
        if isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        elif isinstance(value, dict) and part in value:
            value = value[part]
        else:
            raise FigureError(f"{record['name']}.json has no figure {key!r}")
    return value


def machine_words(record: dict[str, Any]) -> str:
    """'2 cores (CPU model), no GPU, load 6.1-7.3' from a record's machine."""
    m = record["machine"]
    parts = []
    if m.get("cores"):
        parts.append(f"{m['cores']} cores" + (f" ({m['cpu']})" if m.get("cpu") else ""))
    parts.append("no GPU" if m.get("gpu", "none") == "none" else m["gpu"])
    loads = [x for x in (m.get("load_1min_start"), m.get("load_1min_end")) if x is not None]
    if loads:
        parts.append("load " + "-".join(f"{x:.1f}" for x in sorted(set(round(x, 1) for x in loads))))
    return ", ".join(parts)


def short_source(record: dict[str, Any]) -> str:
    commit = record["commit"][:7] + (" with local changes" if record.get("dirty") else "")
    return f"{record['date'][:10]}, commit {commit}, {machine_words(record)}"


def source_line(record: dict[str, Any], page: Path, results: Path = RESULTS) -> str:
    link = os.path.relpath(results / f"{record['name']}.json", page.parent)
    if record.get("recorded_from"):  # its command (often several) is in the file
        return (f"*Recorded from an earlier run in [{record['name']}.json]({link}): {short_source(record)}; "
                f"{record['recorded_from']}.*")
    return f"*Recorded in [{record['name']}.json]({link}): `{record['command']}`, {short_source(record)}.*"


def markdown_table(table: dict[str, Any]) -> str:
    rules = {"l": "---", "r": "---:", "c": ":---:"}
    lines = ["| " + " | ".join(table["columns"]) + " |", "|" + "|".join(rules[a] for a in table["align"]) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in table["rows"]]
    return "\n".join(lines)


def recorded_table(name: str, table: str | None, page: Path, results: Path) -> str:
    record = read(name, results)
    figures = record["figures"]
    if table is None:
        if "table" not in figures:
            raise FigureError(f"{name}.json has no 'table' (its tables: {sorted(figures.get('tables', {}))})")
        body = figures["table"]
    else:
        body = figures.get("tables", {}).get(table)
        if body is None:
            raise FigureError(f"{name}.json has no table {table!r} (its tables: {sorted(figures.get('tables', {}))})")
    return markdown_table(body) + "\n\n" + source_line(record, page, results)


# ---------------------------------------------------------------------------------------------------------
# Tables built from several files


# one model's paper evaluation: the paper's suites x the protocol's episodes x normal, blank, shuffled
PAPER_EVAL_EPISODES = len(PAPER_SUITES) * EPISODES_PER_SUITE * 3
EPISODE_STEPS = TASK_MAX_EPISODE_STEPS  # the worst case: every episode to the step limit
TRAINING_FRAMES = 2_640_000  # the six training sets, three cameras a frame (docs/demos.md)


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 5400 else f"{seconds / 60:.0f} min"


def _link(name: str, page: Path, results: Path) -> str:
    record = read(name, results)
    link = os.path.relpath(results / f"{name}.json", page.parent)
    gpu = record["machine"].get("gpu", "none")
    return f"[{name}]({link}): {record['date'][:10]}, commit {record['commit'][:7]}, {gpu}"


def gpu_figures(page: Path, results: Path) -> str:
    """The one table of GPU figures: what was measured (with its file) and what is projected from it."""
    h100 = read("gpu_h100_one_env", results)
    probe = read("gpu_h100_group_probe", results)
    h200 = read("gpu_h200_batched_path", results)
    agg = lookup(h100, "aggregate_rgb_steps_s_by_procs")
    steps = PAPER_EVAL_EPISODES * EPISODE_STEPS
    src = {n: _link(n, page, results) for n in ("gpu_h100_one_env", "gpu_h100_group_probe", "gpu_h200_batched_path")}
    ep1, ep10 = lookup(h100, "eval_chunk1_s_per_episode"), lookup(h100, "eval_chunk10_s_per_episode")
    procs = lookup(h100, "eval_procs")
    group, raw, ev = (lookup(probe, "group_env_steps_s_16x4"), lookup(h200, "raw_loop_env_steps_s_16x4"),
                      lookup(h200, "eval_env_steps_s_16x4"))
    physics, render = lookup(probe, "physics_ms_per_batch_k4"), lookup(probe, "group_render_ms_k4")
    chunked = 16 * 4 / ((physics + render / 10) / 1000)
    peak = max(agg.values())
    rows = [
        ["one env a process, every camera every step: aggregate over 1 / 4 / 8 / 16 processes",
         " / ".join(f"{agg[k]:,}" for k in ("1", "4", "8", "16")) + " rgb steps/s", "measured (H100)",
         src["gpu_h100_one_env"]],
        [f"`rsb eval random -o rgb --num-procs {procs}`, one env a process, a render every step",
         f"{lookup(h100, 'eval_chunk1_steps_s'):,} steps/s; {ep1} s a {EPISODE_STEPS}-step episode", "measured (H100)",
         src["gpu_h100_one_env"]],
        ["the same, chunks of 10 (cameras rendered on demand)",
         f"{lookup(h100, 'eval_chunk10_steps_s'):,} steps/s; {ep10} s an episode", "measured (H100)",
         src["gpu_h100_one_env"]],
        ["8 processes, state observations (no rendering)", f"{lookup(h100, 'state_steps_s_8procs'):,} steps/s",
         "measured (H100)", src["gpu_h100_one_env"]],
        ["16 processes x K = 4 envs, every camera of a process's K envs in one group call: SAPIEN's calls "
         "in a probe script, not the pack's code", f"{group:,} rgb env-steps/s", "measured (H100)",
         src["gpu_h100_group_probe"]],
        ["the pack's own raw loop, 16 x 4 (physics + group render), before the batched observation (2026-11-28)",
         f"{raw:,} env-steps/s",
         "measured (H200)", src["gpu_h200_batched_path"]],
        ["`rsb eval random -o rgb --num-envs 4 --num-procs 16`, before the batched observation (built env by env)",
         f"{ev:,} env-steps/s", "measured (H200)", src["gpu_h200_batched_path"]],
        *today_rows(page, results),
        [f"a paper evaluation of one model ({PAPER_EVAL_EPISODES:,} episodes of {EPISODE_STEPS} steps), one env a "
         "process, a render every step", _duration(PAPER_EVAL_EPISODES * ep1 / procs),
         f"projected: {PAPER_EVAL_EPISODES:,} x {ep1} s / {procs} workers", "the H100 `rsb eval` row"],
        ["the same, chunks of 10", _duration(PAPER_EVAL_EPISODES * ep10 / procs),
         f"projected: {PAPER_EVAL_EPISODES:,} x {ep10} s / {procs} workers", "the H100 `rsb eval` row"],
        ["the same, 16 x 4 envs, a render every step",
         f"{_duration(steps / group)} / {_duration(steps / raw)} / {_duration(steps / ev)}",
         f"projected: {steps / 1e6:.1f} M steps / {group:,} (probe) / {raw:,} (raw loop) / {ev:,} (`rsb eval` "
         "before the batched observation) steps/s", "the probe and H200 rows"],
        ["the same, 16 x 4 envs, chunks of 10", _duration(steps / chunked),
         f"projected: 64 envs / ({physics} ms physics + {render} ms render / 10) a batch = {chunked:,.0f} steps/s",
         "the probe row (its per-batch figures)"],
        [f"the paper's six training sets ({TRAINING_FRAMES / 1e6:.2f} M frames), one env a process",
         _duration(TRAINING_FRAMES / peak), f"projected: {TRAINING_FRAMES / 1e6:.2f} M / {peak} frames/s (the peak)",
         "the H100 aggregate row"],
        ["the same, K envs rendered in one call", f"at most {_duration(TRAINING_FRAMES / group)}",
         f"projected: {TRAINING_FRAMES / 1e6:.2f} M / {group:,} frames/s or more (no physics step)", "the probe row"],
    ]
    table = {"columns": ["what", "figure", "measured, target or projected", "source"], "align": "lrll",
             "rows": rows}
    return markdown_table(table)


def today_rows(page: Path, results: Path) -> list[list[str]]:
    """Today's batched path on a GPU: `benchmarks/gpu_check.py`'s figures once a GPU box recorded them, else
    the targets they are held to."""
    if not (results / "gpu_check.json").is_file():
        return [["`rsb eval random -o rgb` with its defaults today, against the raw loop of the same run",
                 ">= 2,000 env-steps/s and >= 0.85 of the raw loop", "target, not yet measured",
                 "`python benchmarks/gpu_check.py` on a GPU box"],
                ["training-set rendering today (`render_demos`, 16 x 4)", ">= 2,200 frames/s",
                 "target, not yet measured", "`python benchmarks/gpu_check.py`"]]
    check = read("gpu_check", results)
    gpu, src = check["machine"].get("gpu", "none"), _link("gpu_check", page, results)
    k, procs = lookup(check, "envs"), lookup(check, "procs")
    return [[f"`rsb eval random -o rgb` with its defaults today ({procs} x {k}), against the raw loop of the "
             "same run", f"{lookup(check, 'eval_steady_env_steps_s'):,.0f} env-steps/s; "
             f"{lookup(check, 'eval_over_ceiling'):.2f} of {lookup(check, 'raw_ceiling_env_steps_s'):,.0f}",
             f"measured ({gpu}); target >= 2,000 and >= 0.85", src],
            [f"training-set rendering today (`render_demos`, {procs} x {k})",
             f"{lookup(check, 'training_frames_s'):,.0f} frames/s", f"measured ({gpu}); target >= 2,200", src]]


def episode_cost(page: Path, results: Path) -> str:
    """docs/scale.md's cost of a step and of an episode: the random policy (every episode to the step limit),
    state observations, and rgb rendered every step or on demand, from eval_throughput's two files."""
    state, rgb = read("eval_throughput_random", results), read("eval_throughput_rgb", results)
    (run,) = lookup(state, "runs")[:1]
    every, lazy = lookup(rgb, "every_step"), lookup(rgb, "on_demand")
    chunk = lookup(rgb, "chunk")
    rows = [["state", f"{run['ms_per_step']:.1f} ms", f"{run['s_per_episode']:.2f} s",
             f"{run['steps_per_episode']:.0f}", f"`{state['command']}`"],
            ["rgb, cameras rendered every step", f"{every['ms_per_step']:.0f} ms", f"{every['s_per_episode']:.1f} s",
             f"{every['steps_per_episode']:.0f}", f"`{rgb['command']}`"],
            [f"rgb, render on demand, chunks of {chunk}", f"{lazy['ms_per_step']:.1f} ms",
             f"{lazy['s_per_episode']:.1f} s", f"{lazy['steps_per_episode']:.0f}", "same run"]]
    table = {"columns": ["observations", "per step", "per episode", "steps an episode", "measured with"],
             "align": "lrrrl", "rows": rows}
    return (markdown_table(table) + "\n\n" + source_line(state, page, results) + "\n\n" +
            source_line(rgb, page, results))


CLUSTER_EPISODES = PAPER_EVAL_EPISODES * 10  # ten models
CLUSTER_WORKERS = (16, 64, 256)


def cluster_cpu(page: Path, results: Path) -> str:
    """docs/scale.md's cluster arithmetic: ten models' paper evaluations on CPU workers, projected from the
    per-episode costs of episode_cost (one core a worker, every episode to the step limit)."""
    state, rgb = read("eval_throughput_random", results), read("eval_throughput_rgb", results)
    costs = [("state", lookup(state, "runs")[0]["s_per_episode"]),
             ("rgb, every step", lookup(rgb, "every_step")["s_per_episode"]),
             (f"rgb, on demand, chunks of {lookup(rgb, 'chunk')}", lookup(rgb, "on_demand")["s_per_episode"])]
    rows = [[what, f"{cost:.2f} s", f"{CLUSTER_EPISODES * cost / 3600:,.0f}",
             *(_duration(CLUSTER_EPISODES * cost / n) for n in CLUSTER_WORKERS)] for what, cost in costs]
    table = {"columns": ["observations", "per episode (measured above)", "core-hours",
                         *(f"on {n} workers" for n in CLUSTER_WORKERS)], "align": "lrrrrr", "rows": rows}
    return markdown_table(table) + (f"\n\n*Projected: {CLUSTER_EPISODES:,} episodes x the cost of an episode "
                                    "above, divided by N workers of one core each.*")


def expert_suites(page: Path, results: Path) -> str:
    """docs/expert.md's table of the scripted expert per suite, from expert_success.json: the columns
    benchmarks/expert_success.py prints, those of them the file holds (p95 and the times from its later runs)."""
    record = read("expert_success", results)
    suites = lookup(record, "suites")

    def held(key: str) -> bool:
        return all(key in r for r in suites.values())

    times = [(k, head, fmt) for k, head, fmt in (("plan_time", "plan s", ".3f"), ("sim_time", "sim s", ".2f"),
                                                 ("wall_time", "wall s", ".2f")) if held(k)]
    p95 = held("len_p95")
    columns = ["suite", "seeds", "success", "mean length", *(["p95"] if p95 else []), "max",
               *(head for _, head, _ in times)]
    rows = [[suite, f"{r['n']}", f"{100 * r['success']:.1f} %", f"{r['len_mean']:.1f}",
             *([f"{r['len_p95']:.0f}"] if p95 else []), f"{r['len_max']}", *(format(r[k], fmt) for k, _, fmt in times)]
            for suite, r in suites.items()]
    table = {"columns": columns, "align": "l" + "r" * (len(columns) - 1), "rows": rows}
    n, failures = lookup(record, "episodes"), lookup(record, "failures")
    total = (f"{n - failures:,} successful demos of {n:,} episodes, {lookup(record, 'demos_per_min'):.1f} "
             f"successful demos a minute overall.")
    return markdown_table(table) + "\n\n" + total + "\n\n" + source_line(record, page, results)


RENDERERS: dict[str, Callable[[Path, Path], str]] = {"gpu_figures": gpu_figures, "episode_cost": episode_cost,
                                                    "cluster_cpu": cluster_cpu, "expert_suites": expert_suites}


# ---------------------------------------------------------------------------------------------------------


def render_block(name: str, table: str | None, page: Path, results: Path = RESULTS) -> str:
    if name in RENDERERS and table is None:
        return RENDERERS[name](page, results)
    return recorded_table(name, table, page, results)


def render_value(name: str, key: str, fmt: str | None, results: Path = RESULTS) -> str:
    record = read(name, results)
    if key == "@date":
        return record["date"][:10]
    if key == "@source":
        return short_source(record)
    value = lookup(record, key)
    return format(value, fmt) if fmt else str(value)


def render(text: str, page: Path, results: Path = RESULTS, errors: list[str] | None = None) -> str:
    """The page's text with every marked region rendered from its file. A region that cannot be rendered
    raises FigureError, or, given ``errors``, is left as it is and its error appended there."""
    def guarded(fn: Callable[[re.Match], str]) -> Callable[[re.Match], str]:
        def sub(m: re.Match) -> str:
            try:
                return fn(m)
            except FigureError as e:
                if errors is None:
                    raise
                errors.append(str(e))
                return m.group(0)
        return sub

    def block(m: re.Match) -> str:
        return m.group(1) + render_block(m["name"], m["table"], page, results) + "\n" + m.group(5)

    def inline(m: re.Match) -> str:
        return m.group(1) + render_value(m["name"], m["key"], m["fmt"], results) + m.group(6)

    return INLINE.sub(guarded(inline), BLOCK.sub(guarded(block), text))


def regions(text: str) -> list[tuple[str, str]]:
    """(kind, name) of every marked region of a page."""
    return [("table", m["name"]) for m in BLOCK.finditer(text)] + [("value", m["name"]) for m in INLINE.finditer(text)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 naming each page that differs")
    args = ap.parse_args(argv)
    stale, broken = [], []
    for page in pages():
        text = page.read_text(encoding="utf-8")
        errors: list[str] = []
        new = render(text, page, errors=errors)
        for e in errors:  # the other regions are rendered all the same
            print(f"{page.relative_to(ROOT)}: {e}", file=sys.stderr)
        broken += errors
        if new != text:
            stale.append(page.relative_to(ROOT))
            if not args.check:
                page.write_text(new, encoding="utf-8")
    verb = "differ from their recorded figures" if args.check else "re-rendered"
    print(f"{len(stale)} page(s) {verb}" + ("".join(f"\n  {p}" for p in stale)))
    return 1 if broken or (args.check and stale) else 0


if __name__ == "__main__":
    raise SystemExit(main())
