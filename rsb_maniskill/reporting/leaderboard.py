"""``rsb leaderboard``: several runs side by side, as the paper's main table, with the Random line.

A run is a results document (``results.json``, ``results.py``): read as is from a file, or computed
from a results directory's records (an ``rsb eval --out``, a ``lerobot-eval`` records_dir, a
``vla-eval run`` output of RSBBenchmark), never written back into it. A document's rows are policy
x instruction mode x perturbation; a leaderboard holds the rows of **one protocol** (instruction
mode, perturbation, split, seeds) and **one benchmark version**, so that a column never pools two
of either (vla-eval's rule: no aggregation across protocols), and each row becomes a model. Rows
run on fewer episodes than the protocol's (``EPISODES_PER_SUITE``), or on other seeds, are marked rather than hidden;
two runs of the same policy label are told apart by checkpoint, else by run.

``leaderboard_files.py`` writes its Markdown, CSV and page; ``vla_eval_leaderboard.py`` exports
runs as vla-eval leaderboard records.
"""
from __future__ import annotations

import json
import os
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import (
    Average,
    Rate,
    average,
    avg_suites,
    num_choices,
    suite_order,
)
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE
from rsb_maniskill.reporting.results import (
    RESULTS_FILE,
    SCHEMA_ID,
    ResultsFileError,
    document_problem,
    load_results,
    read_results_file,
    results_document,
    version_problem,
)

RANDOM = "Random (1/N)"  # the random-selection line of the paper's tables
# Keys of a protocol, besides the benchmark version: rows that differ in one never share a column.
PROTOCOL_KEYS = ("instruction_mode", "perturb", "split", "instructions", "first_seed", "episodes_per_suite")


class LeaderboardError(ValueError):
    """Runs that cannot be read, or cannot share one leaderboard: one line naming the fix."""


@dataclass(frozen=True)
class Run:
    """One run: where it was read from (as given) and its results document."""

    source: str
    doc: Mapping[str, Any]


@dataclass(frozen=True)
class Entry:
    """A leaderboard row: a model (one row of a run), or the Random line (``run`` None)."""

    label: str
    row: Mapping[str, Any]  # the results.json row; for Random, its suites only
    run: Run | None
    avg: Average | None  # over the leaderboard's Avg suites (None: no Avg column)
    short: bool = False  # a suite ran on fewer episodes than the protocol's
    off_seeds: bool = False  # a suite's episodes are not the protocol's seeds
    provenance: str = "unverified"  # its episodes: pinned / differ / unverified (evaluation/provenance.py)
    unverified_why: str | None = None  # why unverified: NO_DATA, NO_DIGESTS or AS_FILED (:func:`unverified_notes`)
    differs: bool | None = None  # TSR differs significantly from the best row's (None: not tested, or the best)
    p_best: float | None = None  # the p-value of that test
    p_holm: float | None = None  # ... Holm-adjusted over every pair of rows (the family: see mark_differences)
    test_best: str | None = None  # how it was tested: PAIRED or UNPAIRED
    family: int = 0  # the tests Holm's correction was over (every pair of rows that could be tested)
    also: tuple[str, ...] = ()  # other runs given that hold this same row (listed once)

    @property
    def random(self) -> bool:
        return self.run is None

    @property
    def tsr_mde(self) -> float | None:
        """The smallest TSR difference from this row that a paired run on its episodes (pooled over its
        Avg suites, else all of its suites) detects with 80 % power at 5 % (``stats``, McNemar's exact
        test); None where the rate is undefined or no difference can be detected at its n."""
        from rsb_maniskill.evaluation.stats import minimum_detectable_difference

        if self.random:
            return None
        present = self.avg.present if self.avg else ()
        over = [s for s in present if s in self.row["suites"]] or list(self.row["suites"])
        rate = _pooled_tsr(self.row, over)
        n = sum(self.row["suites"][s]["n"] for s in over if self.row["suites"][s]["tsr"]["value"] is not None)
        return None if rate.value is None else minimum_detectable_difference(rate.value, n)

    @property
    def episodes(self) -> tuple[int, int] | None:
        """Fewest and most episodes over its suites (None for Random)."""
        ns = [s["n"] for s in self.row["suites"].values() if s.get("n")]
        return (min(ns), max(ns)) if ns else None


@dataclass(frozen=True)
class Leaderboard:
    """Models of one protocol and one benchmark version, suites as columns, the Random line last."""

    benchmark_version: str
    protocol: Mapping[str, Any]  # PROTOCOL_KEYS' values, shared by every row
    suites: list[str]
    avg_suites: tuple[str, ...]
    entries: list[Entry] = field(default_factory=list)


# ---------------------------------------------------------------- reading runs
def load_run(path: str | os.PathLike) -> Run:
    """The run at ``path``: an RSB ``results.json`` or a vla-eval ``*_aggregate.json``; or a results
    directory (``episodes.jsonl``, else vla-eval results, else ``results.json``)."""
    from rsb_maniskill.reporting.vla_eval_results import (
        is_vla_eval_results,
        read_vla_eval_records,
        records_from_results,
    )

    p = Path(path)
    try:
        if p.is_file():
            doc = read_results_file(p)
            if not isinstance(doc, dict):
                raise LeaderboardError(f"{p}: not a results document (a JSON object)")
            if "tasks" in doc and "rows" not in doc:  # vla-eval's results file
                doc = results_document(records_from_results(doc, str(p)))
        elif is_vla_eval_results(p):
            doc = results_document(read_vla_eval_records(p))
        elif p.is_dir():
            doc = load_results(p)  # its records (current), else its results.json
        else:
            raise LeaderboardError(f"{p}: no such file or directory: give a results.json or a results directory")
    except LeaderboardError:
        raise
    except ResultsFileError as err:  # names the file itself
        raise LeaderboardError(str(err)) from None
    except FileNotFoundError as err:
        raise LeaderboardError(str(err)) from None
    except (ValueError, OSError) as err:  # a bad JSON file, two versions in one run, not RSB's records
        raise LeaderboardError(f"{p}: {err}") from None
    if doc.get("schema") != SCHEMA_ID:
        raise LeaderboardError(f"{p}: not an RSB results.json ({SCHEMA_ID}) nor vla-eval results of RSBBenchmark")
    if version_problem(doc):
        raise LeaderboardError(f"{p}: {version_problem(doc)}")
    if not doc.get("rows"):
        raise LeaderboardError(f"{p}: holds no episode records yet")
    problem = document_problem(doc)
    if problem:
        from rsb_maniskill.evaluation.store import RECORDS_FILE

        where = p / RESULTS_FILE if p.is_dir() and not (p / RECORDS_FILE).exists() else p
        raise LeaderboardError(f"{where}: {problem}")
    return Run(str(path), doc)


def _run_key(path: str) -> Path:
    p = Path(path).resolve()
    return p.parent if p.name == RESULTS_FILE else p


def check_distinct(runs: Sequence[Run]) -> None:
    """Each run once: a directory and its own results.json are the same run."""
    seen: dict[Path, str] = {}
    for run in runs:
        key = _run_key(run.source)
        if key in seen:
            raise LeaderboardError(f"{seen[key]} and {run.source} are the same run: give each run once")
        seen[key] = run.source


# ---------------------------------------------------------------- one protocol, one version
def select_rows(runs: Sequence[Run], instruction_mode: str | None = None, perturb: str | None = None
                ) -> list[tuple[Run, Mapping[str, Any]]]:
    """The (run, row) pairs of the protocol asked for (all when no filter is given)."""
    check_distinct(runs)
    pairs = [(run, row) for run in runs for row in run.doc["rows"]
             if instruction_mode in (None, row["instruction_mode"]) and perturb in (None, row["perturb"])]
    if not pairs:
        held = sorted({protocol_text({k: row[k] for k in PROTOCOL_KEYS[:2]})  # its mode and perturbation
                       for run in runs for row in run.doc["rows"]})
        raise LeaderboardError(f"no row of {protocol_text({'instruction_mode': instruction_mode, 'perturb': perturb})}"
                               f" in the runs given: they hold {'; '.join(held)}")
    return pairs


def _protocol(run: Run, row: Mapping[str, Any]) -> dict[str, Any]:
    proto = run.doc["protocol"]
    return {"instruction_mode": row["instruction_mode"], "perturb": row["perturb"],
            **{k: proto.get(k) for k in PROTOCOL_KEYS[2:]}}


def protocol_text(protocol: Mapping[str, Any]) -> str:
    """``"normal instructions, no perturbation, split test, ..."``: the keys of ``protocol`` given."""
    words = {
        "instruction_mode": lambda v: f"{v} instructions",
        "perturb": lambda v: "no perturbation" if v == "none" else f"perturbation {v}",
        "split": lambda v: f"split {v}",
        "instructions": lambda v: f"{v} instruction templates",
        "first_seed": lambda v: f"seeds {v:,} + i" if isinstance(v, int) else f"seeds {v} + i",
        "episodes_per_suite": lambda v: f"{v} episodes per suite",
    }
    return ", ".join(words[k](protocol[k]) for k in PROTOCOL_KEYS if protocol.get(k) is not None) or "any protocol"


def _fix_hint(protocols: Sequence[Mapping[str, Any]]) -> str:
    def choice(flag: str, values: set[str], first: str) -> list[str]:
        if len(values) < 2:
            return []
        head, *rest = sorted(values, key=lambda v: (v != first, v))
        return [f"{flag} {head} (or {', '.join(rest)})"]

    flags = choice("--protocol", {p["instruction_mode"] for p in protocols}, "normal")
    flags += choice("--perturb", {p["perturb"] for p in protocols}, "none")
    pick = f"pick one with {' and '.join(flags)}, or " if flags else ""
    return f"{pick}build one leaderboard per protocol (a separate --out each)"


def check_one_protocol(pairs: Sequence[tuple[Run, Mapping[str, Any]]]) -> tuple[str, dict[str, Any]]:
    """The one benchmark version and the one protocol of ``pairs``; LeaderboardError, naming two and
    the fix, otherwise."""
    from rsb_maniskill.version import benchmark_label

    versions: dict[str, list[str]] = defaultdict(list)
    for run, _ in pairs:
        if run.source not in versions[run.doc["benchmark_version"]]:
            versions[run.doc["benchmark_version"]].append(run.source)
    if len(versions) > 1:
        (a, ra), (b, rb) = sorted(versions.items())[:2]
        raise LeaderboardError(f"cannot put {benchmark_label(a)} ({', '.join(ra)}) and {benchmark_label(b)} "
                               f"({', '.join(rb)}) in one column: their episodes differ; build one leaderboard "
                               "per benchmark version (a separate --out each)")
    protocols: dict[tuple, list[str]] = defaultdict(list)
    for run, row in pairs:
        proto = _protocol(run, row)
        protocols[tuple(proto.values())].append(row["row"])
    if len(protocols) > 1:
        found = [dict(zip(PROTOCOL_KEYS, key)) for key in protocols]
        differ = [k for k in PROTOCOL_KEYS if len({p[k] for p in found}) > 1]
        shown = "; ".join(f"{protocol_text({k: p[k] for k in differ})} ({', '.join(rows[:3])}"
                          f"{', ...' if len(rows) > 3 else ''})" for p, rows in zip(found, protocols.values()))
        raise LeaderboardError(f"rows of {len(protocols)} protocols cannot share a column (no aggregation across "
                               f"protocols): {shown}; {_fix_hint(found)}")
    return next(iter(versions)), dict(zip(PROTOCOL_KEYS, next(iter(protocols))))


def told_apart(items: Sequence[tuple[str, str, str | None]]) -> list[str]:
    """Labels for ``(name, run source, checkpoint)`` items: a name that several runs share gets its
    checkpoint when theirs differ, else its run (``"pi05 @ ckpt-a"``, ``"pi05 (results/a)"``)."""
    labels = [name for name, _, _ in items]
    groups: dict[str, list[int]] = defaultdict(list)
    for i, (name, _, _) in enumerate(items):
        groups[name].append(i)
    for name, idx in groups.items():
        if len(idx) < 2 and name != RANDOM:
            continue
        ckpts = [items[i][2] for i in idx]
        by_ckpt = len(idx) > 1 and all(ckpts) and len(set(ckpts)) == len(ckpts)
        for i in idx:
            labels[i] = f"{name} @ {items[i][2]}" if by_ckpt else f"{name} ({items[i][1]})"
    return labels


# ---------------------------------------------------------------- the table
@dataclass(frozen=True)
class _SuiteView:
    """What ``metrics.average`` reads of a suite, from a results.json suite object."""

    n_episodes: int
    gsr: Rate
    tsr: Rate
    nsg: Rate

    @classmethod
    def of(cls, suite: Mapping[str, Any]) -> _SuiteView:
        return cls(suite["n"], *(Rate(**suite[k]) for k in ("gsr", "tsr", "nsg")))


def random_row(suites: Sequence[str]) -> dict[str, Any]:
    """Random target selection: TSR = 1/N and nSG = 0 by definition, exactly (no interval); GSR is
    not defined (no arm grasps)."""
    def rate(v: float | None) -> dict[str, float | None]:
        return {"value": v, "low": None, "high": None}

    return {"row": RANDOM, "policy": RANDOM, "checkpoint": None, "suites": {
        s: {"n_choices": num_choices(s), "n": None, "protocol_seeds": True, "gsr": rate(None),
            "tsr": rate(1.0 / num_choices(s)), "nsg": rate(0.0)} for s in suites}}


def random_average(suites: Sequence[str], over: Sequence[str]) -> Average:
    """The Random line's Avg: the mean of 1/N over the Avg suites shown; GSR undefined."""
    present = [s for s in over if s in suites]
    tsr = sum(1.0 / num_choices(s) for s in present) / len(present) if present else None
    return Average(tuple(over), tuple(present), len(present) == len(over), None, tsr,
                   0.0 if present else None, len(present))


def _sort_key(e: Entry) -> tuple:
    tsr = e.avg.tsr if e.avg else None
    return (e.random, tsr is None, -(tsr or 0.0), e.label.lower())


PAIRED, UNPAIRED = "paired", "unpaired"  # how a row was tested against the best
ALPHA = 0.05


def _records(entry: Entry, suites: Sequence[str]) -> list[Mapping[str, Any]] | None:
    """The episode records of an entry's row (None when its run is a results.json alone)."""
    from rsb_maniskill.evaluation.records import record_row
    from rsb_maniskill.evaluation.store import RECORDS_FILE, read_records

    if entry.run is None or not (Path(entry.run.source) / RECORDS_FILE).exists():
        return None
    recs = read_records(Path(entry.run.source) / RECORDS_FILE)
    return [r for r in recs if record_row(r) == entry.row["row"] and r["suite_id"] in suites]


def _pooled_tsr(row: Mapping[str, Any], suites: Sequence[str]) -> Rate:
    """TSR pooled over ``suites`` (successes over episodes) with its Wilson interval."""
    from rsb_maniskill.evaluation.metrics import wilson_interval

    ss = [row["suites"][s] for s in suites if s in row["suites"] and row["suites"][s]["tsr"]["value"] is not None]
    n = sum(s["n"] for s in ss)
    if not n:
        return Rate(None, None, None)
    k = sum(round(s["tsr"]["value"] * s["n"]) for s in ss)
    return Rate(k / n, *wilson_interval(k, n))


def pair_test(row_a: Mapping[str, Any], row_b: Mapping[str, Any], recs_a: list | None, recs_b: list | None,
              suites: Sequence[str]) -> tuple[float | None, str | None]:
    """TSR of two rows over ``suites`` (both ran them): McNemar's exact test over the episodes both
    runs' records share (``PAIRED``), else the pooled two-proportion z test of their TSR pooled over
    those suites (``UNPAIRED``; None where a run expects too few successes or failures for it)."""
    from rsb_maniskill.evaluation.stats import mcnemar, two_proportions
    from rsb_maniskill.reporting.paired import pair_records

    if recs_a and recs_b:
        pairs = [p for p in pair_records([r for r in recs_a if r["suite_id"] in suites],
                                         [r for r in recs_b if r["suite_id"] in suites])[0]]
        if pairs:
            t = mcnemar([bool(a.get("success")) for a, _ in pairs], [bool(b.get("success")) for _, b in pairs])
            return t.p, PAIRED

    def counts(row: Mapping[str, Any]) -> tuple[int, int]:
        ss = [row["suites"][s] for s in suites if row["suites"][s]["tsr"]["value"] is not None]
        return sum(round(s["tsr"]["value"] * s["n"]) for s in ss), sum(s["n"] for s in ss)

    (ka, na), (kb, nb) = counts(row_a), counts(row_b)
    return two_proportions(ka, na, kb, nb), UNPAIRED


def differences_from_best(pvalues: Mapping[tuple[int, int], float | None], best: int,
                          ) -> dict[int, tuple[float | None, float | None]]:
    """Per row ``j``, the p of its test against row ``best`` and that p Holm-adjusted over the family of
    every pair of rows (``pvalues`` by ``(i, j)``, i < j): the best row is the observed maximum, a pick
    from the data, so its comparisons are among every pair's and only a correction over all pairs holds
    the family-wise error at alpha (over the rows compared with the best alone, five identical rows
    would get a mark about 8 % of the time)."""
    from rsb_maniskill.evaluation.stats import holm

    keys = list(pvalues)
    adjusted = dict(zip(keys, holm([pvalues[k] for k in keys])))
    out = {}
    for (i, j), p in pvalues.items():
        if best in (i, j):
            out[j if i == best else i] = (p, adjusted[(i, j)])
    return out


def mark_differences(entries: list[Entry], suites: Sequence[str],
                     records_of: Callable[[Entry, Sequence[str]], list | None] | None = None) -> list[Entry]:
    """Each model row tested against the best (the first by Avg TSR whose episodes are not known to
    differ from the version's) on TSR over the suites both ran (:func:`pair_test`), marked where that
    test's p, Holm-adjusted over every pair of rows (:func:`differences_from_best`), is below
    :data:`ALPHA`."""
    from dataclasses import replace

    records_of = records_of or _records
    ranked = [e for e in entries if e.provenance != "differ" and e.avg is not None and e.avg.tsr is not None]
    models = [e for e in entries if not e.random and any(s["tsr"]["value"] is not None
                                                         for s in e.row["suites"].values())]
    if len(models) < 2 or not ranked:
        return entries
    best = ranked[0]  # the best row of the version's episodes (a row of other episodes is never the yardstick)
    recs = [records_of(e, suites) for e in models]
    pvalues: dict[tuple[int, int], float | None] = {}
    tests: dict[tuple[int, int], str | None] = {}
    for i, j in ((i, j) for i in range(len(models)) for j in range(i + 1, len(models))):
        shared = [s for s in suites if s in models[i].row["suites"] and s in models[j].row["suites"]]
        if shared:
            pvalues[(i, j)], tests[(i, j)] = pair_test(models[i].row, models[j].row, recs[i], recs[j], shared)
    pos = {id(e): k for k, e in enumerate(models)}
    b = pos[id(best)]
    found = differences_from_best(pvalues, b)
    out = []
    for e in entries:
        j = pos.get(id(e))
        if e is best or j is None or j not in found:
            out.append(e)
            continue
        p, adjusted = found[j]  # p None: too few episodes for the z test, not tested (the notes say so)
        out.append(replace(e, differs=None if p is None else adjusted < ALPHA, p_best=p, p_holm=adjusted,
                           test_best=tests[(min(b, j), max(b, j))],
                           family=sum(v is not None for v in pvalues.values())))
    return out


def check_episodes(pairs: Sequence[tuple[Run, Mapping[str, Any]]], version: str, allow_other: bool) -> None:
    """LeaderboardError for a row whose episodes are not the version's (unless ``allow_other``)."""
    from rsb_maniskill.evaluation.provenance import DIFFER
    from rsb_maniskill.version import benchmark_label

    for run, row in pairs:
        if row.get("episodes") == DIFFER and not allow_other:
            raise LeaderboardError(f"{run.source}: {row['row']}: episodes differ from {benchmark_label(version)} "
                                   "(other question data?): not ranked beside the version's; give "
                                   "--allow-other-episodes to show it, marked")


def _fingerprint(run: Run, row: Mapping[str, Any]) -> str:
    """What makes two rows the same run's: the benchmark version, protocol and the row itself."""
    keep = {k: v for k, v in run.doc.items() if k in ("benchmark_version", "protocol")}
    return json.dumps([keep, row], sort_keys=True, default=str)


def one_each(pairs: Sequence[tuple[Run, Mapping[str, Any]]],
             ) -> tuple[list[tuple[Run, Mapping[str, Any]]], dict[int, list[str]]]:
    """``pairs`` with a row that several runs hold (a folder copied, a results.json beside its own
    directory's copy) kept once, at its first run; and, by the kept pair's index, the other runs."""
    seen: dict[str, int] = {}
    kept: list[tuple[Run, Mapping[str, Any]]] = []
    also: dict[int, list[str]] = defaultdict(list)
    for run, row in pairs:
        key = _fingerprint(run, row)
        if key in seen:
            also[seen[key]].append(run.source)
            continue
        seen[key] = len(kept)
        kept.append((run, row))
    return kept, also


def build_leaderboard(runs: Sequence[Run], instruction_mode: str | None = None, perturb: str | None = None,
                      allow_other_episodes: bool = False) -> Leaderboard:
    """The leaderboard of ``runs``' rows of one protocol (``instruction_mode`` / ``perturb`` pick
    one), by Avg TSR, the Random line last. LeaderboardError for two versions or protocols, or a
    row whose episodes differ from the version's (unless ``allow_other_episodes``: then marked)."""
    pairs, also = one_each(select_rows(runs, instruction_mode, perturb))
    version, protocol = check_one_protocol(pairs)
    check_episodes(pairs, version, allow_other_episodes)
    suites = suite_order({s for _, row in pairs for s in row["suites"]})
    over = avg_suites(suites)
    labels = told_apart([(row["policy"], run.source, row.get("checkpoint")) for run, row in pairs])
    entries = []
    for i, (label, (run, row)) in enumerate(zip(labels, pairs)):
        views = {s: _SuiteView.of(v) for s, v in row["suites"].items()}
        entries.append(Entry(
            label, row, run, average(views, over) if over else None,
            short=any(v["n"] < EPISODES_PER_SUITE for v in row["suites"].values()),
            off_seeds=any(not v["protocol_seeds"] or v["n"] > EPISODES_PER_SUITE for v in row["suites"].values()),
            provenance=row.get("episodes", "unverified"), also=tuple(also.get(i, ())),
            unverified_why=unverified_why(run, row) if row.get("episodes", "unverified") == "unverified" else None))
    entries.sort(key=_sort_key)
    entries = mark_differences(entries, suites)
    entries.append(Entry(RANDOM, random_row(suites), None, random_average(suites, over) if over else None))
    return Leaderboard(version, protocol, suites, over, entries)


# ---------------------------------------------------------------- why a row is unverified
NO_DATA, NO_DIGESTS, AS_FILED = "no data", "no digests", "as filed"


def unverified_why(run: Run, row: Mapping[str, Any]) -> str:
    """Why ``row``'s episodes are unverified: :data:`NO_DATA` (its records carry this version's digests
    and no question data is at hand to check them on), :data:`NO_DIGESTS` (records without them), or
    :data:`AS_FILED` (a results.json read alone: checked, or not, where it was written)."""
    from rsb_maniskill.evaluation.provenance import check_records
    from rsb_maniskill.evaluation.records import perturb_label, row_label
    from rsb_maniskill.evaluation.store import RECORDS_FILE, read_manifest, read_records

    folder = Path(run.source)
    if not (folder / RECORDS_FILE).is_file():
        return AS_FILED
    records = [r for r in read_records(folder / RECORDS_FILE)
               if row_label(str(r.get("policy", "?")), r.get("instruction_mode", "normal"), perturb_label(r))
               == row["row"]]
    return NO_DATA if check_records(records, runs=read_manifest(folder)).unchecked else NO_DIGESTS


def unverified_notes(board: Leaderboard) -> list[str]:
    """The notes naming the unverified rows, one for each reason they are."""
    from rsb_maniskill.version import benchmark_label

    label = benchmark_label(board.benchmark_version)
    words = {
        NO_DATA: "Episodes not checked: no question data at hand to check their digests on (set RSB_DATA_DIR to "
                 "the data they ran on)",
        NO_DIGESTS: f"Episodes unverified (records without episode digests of {label}: written before them, or by "
                    "another version)",
        AS_FILED: "Episodes unverified as their results.json says (written without the question data to check them "
                  "on, or from records without digests; `rsb report` on the run's folder with its data checks them)",
    }
    out = []
    for why, text in words.items():
        rows = [e.label for e in board.entries if not e.random and e.provenance == "unverified"
                and (e.unverified_why or AS_FILED) == why]
        if rows:
            out.append(f"{text}: {', '.join(rows)}.")
    return out
