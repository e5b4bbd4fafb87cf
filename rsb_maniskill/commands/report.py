"""`rsb report`: report.html, results.json and the summaries of a results directory; two runs side by side.

    rsb report results/pi05                  # report.html, results.json
    rsb report vla_eval_out/                 # a `vla-eval run` of RSBBenchmark: also summary.*
    rsb report --compare results/a results/b

The page is ``reporting/page.py`` (written by ``reporting/writer.py``), the results document and
the comparison ``reporting/results.py``, the reading of vla-eval results
``reporting/vla_eval_results.py``.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    from rsb_maniskill.commands.vocab import add_old_spelling
    from rsb_maniskill.evaluation.store import RECORDS_FILE

    p = subparsers.add_parser(
        "report", help="write report.html, results.json and summary.*; --compare: two runs side by side",
        description="Writes RESULTS_DIR/report.html (a self-contained page that opens from disk), "
                    f"RESULTS_DIR/results.json and the summaries (summary.md, .json, .csv, charts) from "
                    f"RESULTS_DIR/{RECORDS_FILE} (an `rsb eval` output directory), all from the same records. "
                    "RESULTS_DIR may also be a `vla-eval run` output directory (or its *_aggregate.json) of "
                    "RSBBenchmark: then the paper's tables are printed and written to summary.* beside it too. "
                    "With --compare A B: the two runs' GSR / TSR / nSG per suite side by side (Wilson 95 % "
                    "intervals) with B - A; with both runs' episode records, paired tests that count scenes "
                    "(counterfactual runs: follow and switch too), else the two-proportion z test; Holm's "
                    "correction over each table's tests (Markdown). "
                    "Records of two benchmark versions never pool.")
    p.add_argument("results_dir", metavar="RESULTS_DIR", nargs="?")
    p.add_argument("--out", default=None, help="page to write (default: RESULTS_DIR/report.html)")
    add_old_spelling(p, "-o", "--out")
    p.add_argument("--title", default=None, help="page title (default: the directory's name)")
    p.add_argument("--compare", nargs=2, metavar=("DIR_A", "DIR_B"), default=None,
                   help="compare two results directories (or directories holding a results.json)")
    p.set_defaults(func=run_report)


def report_vla_eval(path: str | os.PathLike, out: str | os.PathLike | None = None,
                    title: str | None = None) -> Path:
    """Write ``summary.{md,json,csv}``, the charts and ``report.html`` (or ``out``) beside vla-eval
    results and print the paper's tables; returns the page."""
    from rsb_maniskill.reporting.summary import markdown_tables, results_from_records
    from rsb_maniskill.reporting.vla_eval_results import read_vla_eval_records
    from rsb_maniskill.reporting.writer import ReportError, write_html_report, write_report

    records = read_vla_eval_records(path)
    if not records:
        raise ReportError(f"{path}: holds no episode of RSBBenchmark (an empty or unfinished vla-eval results "
                          "file?): give the results of a finished `vla-eval run`")
    results_dir = Path(path) if Path(path).is_dir() else Path(path).parent
    results = results_from_records(records)
    write_report(results, results_dir, records=records)
    print(markdown_tables(results))
    return write_html_report(results_dir, out, records=records, title=title)


def run_report(args: argparse.Namespace) -> int:
    from rsb_maniskill.evaluation.store import RECORDS_FILE, read_manifest, read_records
    from rsb_maniskill.reporting.results import RESULTS_FILE, compare
    from rsb_maniskill.reporting.summary import results_from_records
    from rsb_maniskill.reporting.vla_eval_results import is_vla_eval_results
    from rsb_maniskill.reporting.writer import ReportError, page_path, writable, write_html_report, write_report

    try:
        if args.compare:
            a, b = args.compare
            check_compare_args(args.results_dir, a, b)
            docs = [checked_results(d) for d in (a, b)]
            both_records = all((Path(d) / RECORDS_FILE).exists() for d in (a, b))
            side = compare(*docs, (a, b), rows_optional=both_records, paired=both_records)
            if both_records:
                from rsb_maniskill.reporting.paired import compare_paired

                recs = [read_records(Path(d) / RECORDS_FILE) for d in (a, b)]
                paired = compare_paired(*recs, (a, b))
                same = same_records(*recs)
            else:
                paired = ("Not paired: episode records (episodes.jsonl) are needed in both directories; the rows "
                          "were compared unpaired (the z test above).\n")
                same = _without_stamp(docs[0]) == _without_stamp(docs[1])
            note = (f"Note: {a} and {b} hold the same {'episode records' if both_records else 'results'} (a copy "
                    "of one run?): every difference is 0 and no test can find one; compare two runs.\n\n"
                    if same else "")
            print(note + side + "\n" + paired + "\n" + episodes_lines(a, b), end="")
            return 0
        if not args.results_dir:
            raise ReportError("give RESULTS_DIR, or --compare DIR_A DIR_B")
        if is_vla_eval_results(args.results_dir):  # a `vla-eval run` of RSBBenchmark: summary.* and results.json
            path = report_vla_eval(args.results_dir, args.out, title=args.title)
            src = Path(args.results_dir)
            results = (src if src.is_dir() else src.parent) / RESULTS_FILE
        else:
            source = Path(args.results_dir) / RECORDS_FILE
            records = read_records(source)
            read_manifest(args.results_dir)  # a damaged run.json fails now, before anything is written
            if not source.exists():
                raise ReportError(f"{args.results_dir} has no {RECORDS_FILE}: give the --out directory of an "
                                  "`rsb eval` run")
            if not records:
                raise ReportError(f"{source} holds no episode records yet")
            page_path(args.results_dir, args.out)  # a page that cannot be written fails now, before any file
            # one pass: the summaries, results.json and the page, all from the same records; a read-only
            # results folder is left as it is (the page still goes to --out)
            if writable(args.results_dir):
                results = write_report(results_from_records(records), args.results_dir, records=records)["results"]
            else:
                results = f"not written ({args.results_dir} is read-only; summary.* and results.json neither)"
            path = write_html_report(args.results_dir, args.out, records=records, title=args.title)
    except (ReportError, ValueError, OSError) as err:
        from rsb_maniskill.outdirs import write_error_line

        print(f"rsb report: error: {write_error_line(err) or err}", file=sys.stderr)  # a full disk: path and fix
        return 2
    print(f"results: {results}\nreport: {path}")
    if not args.compare and not is_vla_eval_results(args.results_dir):
        from rsb_maniskill.reporting.results import run_provenance

        print(run_provenance(records, args.results_dir).text())  # pinned kept where no data is at hand
    return 0


def check_compare_args(results_dir: str | None, a: str, b: str) -> None:
    """``--compare A B`` takes no RESULTS_DIR, and two different runs: ReportError (one line) otherwise."""
    from rsb_maniskill.reporting.writer import ReportError

    if results_dir:
        raise ReportError(f"give RESULTS_DIR ({results_dir}) or --compare DIR_A DIR_B, not both: --compare reads "
                          "only its two directories")
    if Path(a).resolve() == Path(b).resolve():
        raise ReportError(f"--compare {a} {b} compares a run with itself (every difference is 0): give two runs")


def same_records(a: list, b: list) -> bool:
    """Whether two runs' records are the same records (a copied folder): the same episodes with the
    same outcomes, field for field."""
    import json

    def key(recs: list) -> list[str]:
        return sorted(json.dumps(r, sort_keys=True, default=str) for r in recs)

    return bool(a) and len(a) == len(b) and key(a) == key(b)


def _without_stamp(doc: dict) -> dict:
    return {k: v for k, v in doc.items() if k != "created"}


def checked_results(results_dir: str) -> dict:
    """The results document of a directory (``results.load_results``); one read from a results.json
    alone is checked field by field first: ReportError naming the file and the field."""
    from rsb_maniskill.evaluation.store import RECORDS_FILE
    from rsb_maniskill.reporting.results import RESULTS_FILE, document_problem, load_results
    from rsb_maniskill.reporting.writer import ReportError

    d = Path(results_dir)
    try:
        doc = load_results(d)  # a results.json that is not JSON, or nested too deep: ValueError naming it
    except ValueError as err:
        raise ReportError(str(err)) from None
    if (d / RECORDS_FILE).exists():
        return doc
    if not isinstance(doc, dict) or not isinstance(doc.get("rows"), list) or "benchmark_version" not in doc:
        raise ReportError(f"{d / RESULTS_FILE}: not a results document (a JSON object with benchmark_version and "
                          "rows): give an `rsb eval` --out directory or its results.json")
    problem = document_problem(doc)
    if problem:
        raise ReportError(f"{d / RESULTS_FILE}: {problem}")
    return doc


def episodes_lines(*dirs: str) -> str:
    """Per run: whether its episodes are the benchmark version's (``evaluation/provenance.py``), from
    its records (the line ``rsb report`` prints: a pinned verdict kept where no data is at hand to
    re-check it), else its results.json's rows."""
    from rsb_maniskill.evaluation.provenance import UNVERIFIED
    from rsb_maniskill.evaluation.store import RECORDS_FILE, read_records
    from rsb_maniskill.reporting.results import load_results, run_provenance

    out = []
    for d in dirs:
        if (Path(d) / RECORDS_FILE).exists():
            out.append(f"{d}: {run_provenance(read_records(Path(d) / RECORDS_FILE), d).text()}")
        else:
            verdicts = sorted({r.get("episodes", UNVERIFIED) for r in load_results(d)["rows"]})
            out.append(f"{d}: episodes {'/'.join(verdicts)} (its results.json)")
    return "\n".join(out) + "\n"
