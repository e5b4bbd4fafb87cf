"""``results.json``: a run's numbers in a versioned schema a leaderboard can take as is, and
``rsb report --compare A B``.

One document per results directory (``rsb eval`` writes it with the summary, ``rsb report``
rewrites it): the benchmark version of the episodes, the protocol, the code that wrote it, and per
row (policy x instruction mode x perturbation) GSR / TSR / nSG with Wilson 95 % intervals per suite
and their Avg over the paper's suites. ``results.schema.json`` beside this module is the schema
(JSON Schema 2020-12); ``SCHEMA_VERSION`` changes with any change to it. docs/evaluation.md
describes the fields.
"""
from __future__ import annotations

import json
import os
from collections import defaultdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import PAPER_SUITES, Rate, SuiteMetrics, average, num_choices, summarize
from rsb_maniskill.evaluation.provenance import Provenance, check_records
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, dedupe, one_version, perturb_label, row_label
from rsb_maniskill.evaluation.store import RECORDS_FILE, read_manifest, read_records
from rsb_maniskill.reporting.cells import NA, ci, delta, p_value, pct

RESULTS_FILE = "results.json"
METRIC_NAMES = {"gsr": "GSR", "tsr": "TSR", "nsg": "nSG"}  # as the paper and every table write them
SCHEMA_FILE = Path(__file__).with_name("results.schema.json")
SCHEMA_ID = "rsb-ms-results"
SCHEMA_VERSION = 1


def _rate(rate: Rate) -> dict[str, float | None]:
    return {"value": rate.value, "low": rate.low, "high": rate.high}


def _suite(m: SuiteMetrics, seeds: set[int]) -> dict[str, Any]:
    from rsb_maniskill.evaluation.protocol import eval_seeds

    protocol = seeds == set(eval_seeds(m.suite_id, max(1, m.n_episodes)))  # the protocol's first n episodes
    return {"n_choices": m.n_choices, "n": m.n_episodes, "protocol_seeds": protocol,
            "gsr": _rate(m.gsr), "tsr": _rate(m.tsr), "nsg": _rate(m.nsg)}


def _groups(records: Iterable[Mapping[str, Any]]) -> dict[tuple[str, str, str], list[Mapping[str, Any]]]:
    """The records of each row (policy, instruction mode, perturbation); counterfactual ones are none's."""
    groups: dict[tuple[str, str, str], list[Mapping[str, Any]]] = defaultdict(list)
    for r in records:
        if r.get("instruction_mode") == COUNTERFACTUAL:  # a diagnosis, not a score: summary.json's counterfactual
            continue
        groups[(str(r.get("policy", "?")), r.get("instruction_mode", "normal"), perturb_label(r))].append(r)
    return groups


def _seeds_per_suite(recs: Iterable[Mapping[str, Any]]) -> dict[str, set[int]]:
    seeds: dict[str, set[int]] = defaultdict(set)
    for r in recs:
        seeds[r["suite_id"]].add(int(r["seed"]))
    return seeds


def earlier_rows(results_dir: str | os.PathLike) -> dict[str, Mapping[str, Any]]:
    """The rows of the ``results.json`` already in ``results_dir``, by label (none when it has none, or
    one that cannot be read): what an earlier check found of its episodes."""
    try:
        doc = json.loads((Path(results_dir) / RESULTS_FILE).read_text(encoding="utf-8"))
        return {str(row["row"]): row for row in doc["rows"] if isinstance(row, dict) and "row" in row}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def _earlier_verdict(earlier: Mapping[str, Any] | None, seeds: Mapping[str, set[int]]) -> str | None:
    """The verdict an earlier results.json row gave the same episodes (its suites, each with as many of
    the protocol's seeds or not, as ``seeds``), else None."""
    from rsb_maniskill.evaluation.protocol import eval_seeds

    if not earlier or not isinstance(earlier.get("suites"), dict):
        return None
    had = {s: (v.get("n"), v.get("protocol_seeds")) for s, v in earlier["suites"].items() if isinstance(v, dict)}
    now = {s: (len(ss), ss == set(eval_seeds(s, len(ss)))) for s, ss in seeds.items()}
    return earlier.get("episodes") if had == now else None


def run_provenance(records: Sequence[Mapping[str, Any]], results_dir: str | os.PathLike) -> Provenance:
    """Whether a results directory's records are the version's episodes (``provenance.check_records``
    on the data each run was given), keeping the PINNED its results.json gave every row of the same
    episodes when this check finds no question data to be made on (``Provenance.keep``)."""
    found = check_records(records, runs=read_manifest(results_dir))
    if not found.unchecked or any(r.get("instruction_mode") == COUNTERFACTUAL for r in records):
        return found  # (counterfactual episodes have no row there: nothing proved them)
    earlier = earlier_rows(results_dir)
    verdicts = {_earlier_verdict(earlier.get(row_label(*key)), _seeds_per_suite(recs))
                for key, recs in _groups(records).items()}
    return found.keep(verdicts.pop() if len(verdicts) == 1 else None)


def results_document(records: Iterable[Mapping[str, Any]], runs: Mapping[str, Mapping[str, Any]] | None = None,
                     earlier: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """The results document of ``records`` (one benchmark version: VersionMixError otherwise);
    ``runs`` is ``run.json``'s per-policy settings (checkpoint id, package version and commit of
    the run), when the directory has one; ``earlier`` the rows of the results.json it replaces (a row
    of the same episodes keeps the PINNED proven there where no question data is at hand now)."""
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE, EVAL_ENV_KWARGS, EVAL_SEED_BASE
    from rsb_maniskill.version import BENCHMARK, version_fields

    records = dedupe(records)
    version = one_version(records)
    rows = []
    for (policy, mode, perturb), recs in _groups(records).items():
        metrics = summarize(recs)
        seeds = _seeds_per_suite(recs)
        suites = {s: _suite(m, seeds[s]) for s, m in metrics.items()}
        avg = average(metrics)
        run = (runs or {}).get(policy, {})
        label = row_label(policy, mode, perturb)
        found = check_records(recs, runs=runs).keep(_earlier_verdict((earlier or {}).get(label), seeds))
        rows.append({
            "row": label, "policy": policy, "instruction_mode": mode, "perturb": perturb,
            "checkpoint": run.get("checkpoint"), "rsb_maniskill_version": run.get("rsb_version"),
            "code_commit": run.get("code_commit"), "suites": suites,
            "average": {"suites": list(avg.present), "complete": avg.complete, "gsr": avg.gsr, "tsr": avg.tsr,
                        "nsg": avg.nsg},
            "episodes": found.verdict,  # pinned / differ / unverified (provenance.py)
            "full_protocol": all(s in suites and suites[s]["n"] == EPISODES_PER_SUITE and suites[s]["protocol_seeds"]
                                 for s in PAPER_SUITES),
        })
    fields = version_fields()
    return {
        "schema": SCHEMA_ID, "schema_version": SCHEMA_VERSION, "benchmark": BENCHMARK,
        "benchmark_version": version or fields["benchmark_version"],
        "protocol": {**EVAL_ENV_KWARGS, "first_seed": EVAL_SEED_BASE, "episodes_per_suite": EPISODES_PER_SUITE,
                     "avg_suites": list(PAPER_SUITES)},
        "rsb_maniskill_version": fields["rsb_maniskill_version"], "code_commit": fields["code_commit"],
        "created": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "rows": rows,
    }


def write_results(results_dir: str | os.PathLike, records: Iterable[Mapping[str, Any]]) -> Path:
    """Write ``results_dir/results.json`` for ``records`` (whole: a reader never sees half of it)."""
    path = Path(results_dir) / RESULTS_FILE
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    text = json.dumps(results_document(records, read_manifest(results_dir), earlier_rows(results_dir)), indent=1) + "\n"
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except BaseException:  # a full disk: no half-written temp file left beside it
        tmp.unlink(missing_ok=True)
        raise
    return path


MAX_DEPTH = 32  # a results document nests 6 levels; one nested deeper is not one (and costs recursion)


class ResultsFileError(ValueError):
    """A results file that cannot be read as JSON: one line that names it."""


def read_results_file(path: str | os.PathLike) -> Any:
    """The JSON of a results file; ResultsFileError (one line, naming the file and where) for text that is not
    JSON, or JSON nested deeper than :data:`MAX_DEPTH` levels (read without recursion, so a 10,000-deep
    file is named, not a RecursionError)."""
    path = Path(path)
    text = path.read_text(encoding="utf-8", errors="replace")
    deep = _too_deep(text)
    if deep is not None:
        raise ResultsFileError(f"{path}: not a results document: JSON nested over {MAX_DEPTH} levels deep at character "
                         f"{deep:,} (a results.json nests 6)")
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise ResultsFileError(f"{path}: not a results document: {err}") from None


def _too_deep(text: str) -> int | None:
    """The offset where ``text``'s brackets (outside strings) first nest deeper than MAX_DEPTH, else None."""
    import re

    depth = 0
    for m in re.finditer(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', text):
        ch = m.group()
        if ch in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                return m.start()
        elif ch in "]}":
            depth -= 1
    return None


def load_results(results_dir: str | os.PathLike) -> dict[str, Any]:
    """The results document of a directory, computed from its ``episodes.jsonl`` (so that it is
    current), else read from its ``results.json`` (a file shared alone)."""
    d = Path(results_dir)
    if (d / RECORDS_FILE).exists():
        return results_document(read_records(d / RECORDS_FILE), read_manifest(d), earlier_rows(d))
    if (d / RESULTS_FILE).exists():
        return read_results_file(d / RESULTS_FILE)
    raise FileNotFoundError(f"{d} holds neither {RECORDS_FILE} nor {RESULTS_FILE}: give an `rsb eval` --out directory")


# ---------------------------------------------------------------------------------- --compare
def _ci(r: Mapping[str, float | None]) -> str:
    return ci(r["value"], r["low"], r["high"])


def _pairs(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[tuple[Mapping[str, Any], Mapping[str, Any]]]:
    """Rows to put side by side: the one row of each run, else the rows of the same label."""
    if len(a["rows"]) == 1 and len(b["rows"]) == 1:
        return [(a["rows"][0], b["rows"][0])]
    rb = {r["row"]: r for r in b["rows"]}
    return [(r, rb[r["row"]]) for r in a["rows"] if r["row"] in rb]


def _counts(suite: Mapping[str, Any], key: str) -> tuple[int, int] | None:
    """What a suite's rate counts: successes (GSR, TSR: of its episodes; nSG: of its grasps, the
    share nSG rescales), None where undefined."""
    n = suite["n"]
    if key == "nsg":
        s, g = suite["tsr"]["value"], suite["gsr"]["value"]
        return None if s is None or not g else (round(s * n), round(g * n))
    v = suite[key]["value"]
    return None if v is None else (round(v * n), n)


def compare(a: Mapping[str, Any], b: Mapping[str, Any], names: tuple[str, str] = ("A", "B"),
            rows_optional: bool = False, paired: bool = False) -> str:
    """Markdown: two runs' rows side by side, per suite and metric, with B - A. Unpaired (``paired``
    False: no records of the same episodes to pair) each cell is tested by the pooled two-proportion z
    test (``stats.two_proportions``; nSG as its share of grasps on the target), Holm-corrected over
    the table; paired, the paired comparison that follows tests them and this table shows values
    only. ValueError (one line) when their benchmark versions differ, or when no row pairs (unless
    ``rows_optional``: runs of counterfactual scenes alone have no row, their paired comparison of
    records is all there is; a line says so)."""
    from rsb_maniskill.evaluation.stats import ALPHA, holm_marks, two_proportions
    from rsb_maniskill.version import benchmark_label

    if a["benchmark_version"] != b["benchmark_version"]:
        raise ValueError(f"cannot compare {benchmark_label(a['benchmark_version'])} ({names[0]}) with "
                         f"{benchmark_label(b['benchmark_version'])} ({names[1]}): their episodes differ")
    pairs = _pairs(a, b)
    if not pairs and rows_optional:
        return (f"Benchmark: {benchmark_label(a['benchmark_version'])}. A = {names[0]}, B = {names[1]}. No rows "
                f"to put side by side ({names[0]}: {[r['row'] for r in a['rows']]}, {names[1]}: "
                f"{[r['row'] for r in b['rows']]}; counterfactual scenes are a diagnosis, not rows of "
                "results.json): the paired comparison of their episodes follows.\n")
    if not pairs:
        raise ValueError(f"no row to compare: {names[0]} has {[r['row'] for r in a['rows']]}, "
                         f"{names[1]} has {[r['row'] for r in b['rows']]} (rows pair by label, or one row each)")
    shared = [(ra, rb) for ra, rb in pairs if set(ra["suites"]) & set(rb["suites"])]
    if not shared:
        raise ValueError(f"{names[0]} ({', '.join(sorted({s for r in a['rows'] for s in r['suites']}))}) and "
                         f"{names[1]} ({', '.join(sorted({s for r in b['rows'] for s in r['suites']}))}) share "
                         "no suite: nothing to compare")
    cells = [(ra, rb, suite, key) for ra, rb in shared for suite in ra["suites"] if suite in rb["suites"]
             for key in METRIC_NAMES]
    ps: list[float | None] = []
    for ra, rb, suite, key in cells:
        x, y = _counts(ra["suites"][suite], key), _counts(rb["suites"][suite], key)
        ps.append(None if paired or x is None or y is None else two_proportions(*x, *y))
    marks = holm_marks([(p, None, None) for p in ps])
    tested = sum(p is not None for p in ps)
    if paired:
        how = ("intervals: Wilson 95 % (estimates, not a test: the two runs share episodes, and the paired "
               "comparison below tests them).")
    else:
        how = (f"intervals: Wilson 95 %. Test: the pooled two-proportion z test of A against B (nSG: as its share "
               f"of grasps on the target), {MIN_EXPECTED_TEXT}; family: the {tested} tests of this table, Holm's "
               f"correction; * : Holm p < {ALPHA}. Overlapping intervals are not a test.")
    out = [f"Benchmark: {benchmark_label(a['benchmark_version'])}. A = {names[0]}, B = {names[1]}; {how}"]
    found = {(id(ra), suite, key): (p, mk) for (ra, _, suite, key), p, mk in zip(cells, ps, marks)}
    for ra, rb in shared:
        head = "| Suite | Metric | A (n) | B (n) | B - A |" + ("" if paired else " z test p | Holm p |")
        lines = [head, "|---|---|:---:|:---:|:---:|" + ("" if paired else ":---:|:---:|")]
        for suite in [s for s in ra["suites"] if s in rb["suites"]]:
            sa, sb = ra["suites"][suite], rb["suites"][suite]
            for key in METRIC_NAMES:
                x, y = sa[key], sb[key]
                row = f"| {suite} | {METRIC_NAMES[key]} | {_ci(x)} ({sa['n']}) | {_ci(y)} ({sb['n']}) | " \
                      f"{delta(y['value'], x['value'])} |"
                if not paired:
                    p, mk = found[(id(ra), suite, key)]
                    holm_p = NA if p is None else p_value(mk.p_holm) + (" *" if mk.significant else "")
                    row += f" {NA if p is None else p_value(p)} | {holm_p} |"
                lines.append(row)
        for key in METRIC_NAMES:
            x, y = ra["average"][key], rb["average"][key]
            lines.append(f"| Avg | {METRIC_NAMES[key]} | {pct(x)} | {pct(y)} | {delta(y, x)} |"
                         + ("" if paired else " | |"))
        only = sorted(set(ra["suites"]) ^ set(rb["suites"]))
        note = f"\n\nIn one run only: {', '.join(only)}." if only else ""
        out.append(f"### {ra['row']} (A) vs {rb['row']} (B), %\n\n" + "\n".join(lines) + note)
    return "\n\n".join(out) + "\n"


MIN_EXPECTED_TEXT = ("n/a where a run expects under 5 successes or failures at the pooled rate (the z test's rule: "
                     "there its size is not 5 %)")


# ---------------------------------------------------------------------------------- checking one
RATE_RANGES = {"gsr": (0.0, 1.0), "tsr": (0.0, 1.0), "nsg": (-1.0, 1.0)}  # nSG >= -1/(N-1) >= -1


def _number_problem(x: Any, low: float, high: float) -> str | None:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return f"{x!r} is not a number"
    if x != x or x in (float("inf"), float("-inf")):
        return f"{x} is not a finite number"
    if not low <= x <= high:
        return f"{100 * x:g} % is outside [{100 * low:g}, {100 * high:g}] %"
    return None


def shape_problem(doc: Any) -> str | None:
    """The first place where a results document is not the shape its readers walk (a mapping where one
    is due, a list of rows, a suite id this code knows), as ``"field: what"``; None if none. Checked
    in code, so that a hand-edited file is refused in one line even without jsonschema."""
    if not isinstance(doc, Mapping):
        return f"document: {type(doc).__name__} where a JSON object is due"
    rows = doc.get("rows")
    if not isinstance(rows, list):
        return f"rows: {type(rows).__name__} where a list of rows is due"
    for i, row in enumerate(rows):
        if not isinstance(row, Mapping):
            return f"rows[{i}]: {type(row).__name__} where a row (a JSON object) is due"
        for key in ("row", "policy", "instruction_mode", "perturb"):
            if not isinstance(row.get(key), str):
                return f"rows[{i}].{key}: {row.get(key)!r} where a string is due"
        suites = row.get("suites")
        if not isinstance(suites, Mapping):
            return f"rows[{i}].suites: {type(suites).__name__} where a mapping of suite ids is due"
        for suite, value in suites.items():
            try:
                num_choices(suite)
            except (ValueError, KeyError, IndexError):
                return f"rows[{i}].suites: {suite!r} is not a suite id of this benchmark"
            if not isinstance(value, Mapping):
                return f"rows[{i}].suites.{suite}: {type(value).__name__} where a suite's rates are due"
        if not isinstance(row.get("average", {}), Mapping):
            return f"rows[{i}].average: {type(row.get('average')).__name__} where a JSON object is due"
    return None


def version_problem(doc: Mapping[str, Any]) -> str | None:
    """``"schema_version: what"`` where a document's schema version is not this code's, else None."""
    v = doc.get("schema_version")
    if "schema_version" not in doc:
        return f"schema_version: missing (a results.json of this rsb_maniskill has {SCHEMA_VERSION})"
    if isinstance(v, bool) or not isinstance(v, int):
        kind = {"str": "string", "float": "number", "dict": "JSON object", "list": "list", "NoneType": "null"}
        return (f"schema_version: {json.dumps(v)} is a {kind.get(type(v).__name__, type(v).__name__)} where the "
                f"number {SCHEMA_VERSION} is due")
    if v != SCHEMA_VERSION:
        return (f"schema_version: {v}, this rsb_maniskill reads {SCHEMA_VERSION}: run the rsb_maniskill that "
                "wrote it")
    return None


def _interval_problem(rate: Mapping[str, Any], n: int) -> str | None:
    """Where a GSR / TSR's value and interval are not those of ``n`` episodes (the count value x n a
    whole number, the interval Wilson's at n): an edited n (10^30 beside an interval of 2 episodes)."""
    from rsb_maniskill.evaluation.metrics import wilson_interval

    v, lo, hi = rate.get("value"), rate.get("low"), rate.get("high")
    if v is None or lo is None or hi is None:
        return None
    k = v * n
    if abs(k - round(k)) > 1e-6 * max(1.0, k):
        return f"a rate of {100 * v:g} % is no whole number of {n:,} episodes"
    k = min(max(round(k), 0), n)
    want = wilson_interval(k, n)
    if abs(want[0] - lo) > 1e-6 or abs(want[1] - hi) > 1e-6:
        return (f"[{100 * lo:.1f}, {100 * hi:.1f}] % is not the Wilson interval of {k:,} of {n:,} episodes "
                f"([{100 * want[0]:.1f}, {100 * want[1]:.1f}] %): its n or its rate was edited")
    return None


def document_problem(doc: Mapping[str, Any]) -> str | None:
    """The first thing wrong with a results document, as ``"field: what"`` (None if none): its schema
    version, episode counts and the rates' types and ranges (finite, within [0, 1], nSG within
    [-1, 1], low <= value <= high, GSR / TSR intervals Wilson's at the suite's n), checked in code;
    then the shipped schema, where jsonschema is installed."""
    shape = shape_problem(doc) or version_problem(doc)
    if shape:
        return shape
    for i, row in enumerate(doc.get("rows") or []):
        for suite, s in (row.get("suites") or {}).items():
            where = f"rows[{i}].suites.{suite}"
            n = s.get("n") if isinstance(s, Mapping) else None
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                return f"{where}.n: {n!r} is not an episode count (a whole number >= 1)"
            for key, (low, high) in RATE_RANGES.items():
                rate = s.get(key)
                if not isinstance(rate, Mapping):
                    return f"{where}.{key}: not a rate object (value, low, high)"
                for part in ("value", "low", "high"):
                    bad = _number_problem(rate.get(part), low, high)
                    if bad:
                        return f"{where}.{key}.{part}: {bad}"
                v, lo, hi = rate.get("value"), rate.get("low"), rate.get("high")
                if v is not None and lo is not None and hi is not None and not lo <= v <= hi:
                    return f"{where}.{key}: its interval [{lo}, {hi}] does not hold its value {v}"
                edited = _interval_problem(rate, n) if key != "nsg" else None
                if edited:
                    return f"{where}.n: {n:,} episodes do not fit {where}.{key}: {edited}"
        avg = row.get("average")
        for key, (low, high) in RATE_RANGES.items():
            bad = _number_problem(avg.get(key), low, high) if isinstance(avg, Mapping) else None
            if bad:
                return f"rows[{i}].average.{key}: {bad}"
    try:
        import jsonschema
    except ImportError:  # a runtime install without the dev extra: the checks above stand
        return None
    schema = json.loads(SCHEMA_FILE.read_text())
    error = jsonschema.exceptions.best_match(jsonschema.Draft202012Validator(schema).iter_errors(doc))
    if error is None:
        return None
    field = ".".join(str(p) if isinstance(p, str) else f"[{p}]" for p in error.absolute_path).replace(".[", "[")
    return f"{field or 'document'}: {error.message}"
