"""GSR / TSR / nSG with Wilson 95% intervals, suite averages and the paper's error analysis.

Everything here is a pure function of episode records (dicts, see ``records.py``), so a summary
never depends on how, or in how many sittings, the episodes were run.

Definitions (paper section 4.4, appendix C):
    GSR = #episodes where a candidate block was grasped / #episodes
    TSR = #episodes that succeeded (correct block placed in the zone) / #episodes
    nSG = (TSR/GSR - 1/N) / (1 - 1/N)   undefined (None) when GSR = 0
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.env_ids import PAPER_OBJECT_SUITES, PAPER_SUITES
from rsb_maniskill.objects.family import split_env_id
from rsb_maniskill.semantic.suites import parse_suite_id

# Two-sided 95%: the 0.975 quantile of the standard normal.
Z95 = 1.959963984540054


def num_choices(suite_id: str) -> int:
    """N of a suite id (``"RSB-General-10"``, ``"RSB-General-10-Objects"`` -> 10), as the semantic
    engine parses it."""
    return parse_suite_id(split_env_id(suite_id)[0])[1]


def wilson_interval(k: float, n: float, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n.

    Chosen over the normal approximation because it stays inside [0, 1] and keeps its coverage at
    rates near 0 or 1, which is where RSB results live (TSR of a few percent, oracle near 100%).
    ``k`` and ``n`` may be effective counts (clustered samples: ``n`` over the design effect).
    Returns (nan, nan) when n = 0.
    """
    if n < 0 or k < 0 or k > n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    z2 = z * z
    denom = 1.0 + z2 / n
    center = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    lo, hi = center - half, center + half
    # The bounds are exactly 0 at k = 0 and 1 at k = n; pin them there against float round-off.
    lo = 0.0 if k == 0 else min(max(0.0, lo), p)
    hi = 1.0 if k == n else max(min(1.0, hi), p)
    return (lo, hi)


def nsg(tsr: float, gsr: float, n_choices: int) -> float | None:
    """Normalized semantic grounding: 0 = random target among grasps, 1 = always the right one."""
    if gsr <= 0:
        return None
    chance = 1.0 / n_choices
    return (tsr / gsr - chance) / (1.0 - chance)


@dataclass(frozen=True)
class Rate:
    """A proportion with its Wilson 95% interval; ``value`` is None when undefined."""

    value: float | None
    low: float | None
    high: float | None

    @classmethod
    def of(cls, k: int, n: int) -> "Rate":
        if n == 0:
            return cls(None, None, None)
        lo, hi = wilson_interval(k, n)
        return cls(k / n, lo, hi)


@dataclass(frozen=True)
class ErrorAnalysis:
    """Paper Table 7 plus no-grasp.

    Of the grasped-but-failed episodes (``n_grasped_failed``): ``not_placed`` held the correct block
    at some point but it did not end in the zone; ``wrong_target`` only ever grasped wrong blocks.
    The two partition that subset. ``no_grasp`` counts episodes (of all) with no grasp at all.
    """

    n_episodes: int
    n_grasped_failed: int
    not_placed: int
    wrong_target: int
    no_grasp: int

    def fractions(self) -> dict[str, float | None]:
        """Shares as in the paper: of the grasped-but-failed subset, and no-grasp of all episodes."""
        f = self.n_grasped_failed
        return {
            "not_placed": self.not_placed / f if f else None,
            "wrong_target": self.wrong_target / f if f else None,
            "no_grasp": self.no_grasp / self.n_episodes if self.n_episodes else None,
        }


@dataclass(frozen=True)
class SuiteMetrics:
    """GSR, TSR and nSG of one policy on one suite."""

    suite_id: str
    n_choices: int
    n_episodes: int
    n_grasped: int
    n_success: int
    gsr: Rate
    tsr: Rate
    nsg: Rate
    errors: ErrorAnalysis
    # Records with success but no grasp flag (pushed into the zone?); counted as grasped so that
    # TSR <= GSR. Should be 0 with the RSB tasks; reported so that it cannot hide.
    n_success_without_grasp: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["errors"]["fractions"] = self.errors.fractions()
        return d


def _flag(record: Mapping[str, Any], key: str) -> bool:
    value = record.get(key, False)
    return bool(value)


# An episode's class in the error analysis, in the order the report lists them.
OUTCOMES: tuple[str, ...] = ("success", "not_placed", "wrong_target", "no_grasp")


def outcome(record: Mapping[str, Any]) -> str:
    """``success``; else ``no_grasp`` without any grasp; else (grasped but failed) ``not_placed``
    when the correct block was grasped at some point, ``wrong_target`` when only wrong ones were."""
    if _flag(record, "success"):
        return "success"
    if not _flag(record, "grasped_any"):
        return "no_grasp"
    return "not_placed" if _flag(record, "grasped_correct") else "wrong_target"


def suite_metrics(records: Iterable[Mapping[str, Any]], suite_id: str) -> SuiteMetrics:
    """Metrics of the records of one suite (records of other suites are an error, not ignored)."""
    n_choices = num_choices(suite_id)
    n = grasped = success = no_grasp_success = not_placed = wrong_target = no_grasp = 0
    for r in records:
        if r.get("suite_id", suite_id) != suite_id:
            raise ValueError(f"record of suite {r.get('suite_id')!r} passed to suite_metrics({suite_id!r})")
        n += 1
        kind = outcome(r)
        ok, g = kind == "success", kind != "no_grasp"
        no_grasp_success += ok and not _flag(r, "grasped_any")
        grasped += g
        success += ok
        no_grasp += kind == "no_grasp"
        not_placed += kind == "not_placed"
        wrong_target += kind == "wrong_target"
    gsr = Rate.of(grasped, n)
    tsr = Rate.of(success, n)
    # nSG interval: Wilson on the conditional rate success | grasped, mapped through the affine nSG
    # formula (GSR's count is taken as given).
    if grasped:
        c = Rate.of(success, grasped)
        chance = 1.0 / n_choices
        aff = lambda p: (p - chance) / (1.0 - chance)  # noqa: E731
        nsg_rate = Rate(aff(c.value), aff(c.low), aff(c.high))
    else:
        nsg_rate = Rate(None, None, None)
    errors = ErrorAnalysis(n, grasped - success, not_placed, wrong_target, no_grasp)
    return SuiteMetrics(suite_id, n_choices, n, grasped, success, gsr, tsr, nsg_rate, errors, no_grasp_success)


def suite_order(suite_ids: Iterable[str]) -> list[str]:
    """The paper's six suites in its column order, then their objects twins, then any others
    (Direct) by name and N."""
    ids = set(suite_ids)
    paper = PAPER_SUITES + PAPER_OBJECT_SUITES

    def key(s: str) -> tuple:
        base, targets = split_env_id(s)
        head, _, n = base.rpartition("-")
        return (targets, head, int(n) if n.isdigit() else 0, s)

    return [s for s in paper if s in ids] + sorted(ids - set(paper), key=key)


def group_by_suite(records: Iterable[Mapping[str, Any]]) -> dict[str, list[Mapping[str, Any]]]:
    """Records keyed by ``suite_id``, suites in first-seen order."""
    out: dict[str, list[Mapping[str, Any]]] = {}
    for r in records:
        out.setdefault(r["suite_id"], []).append(r)
    return out


def summarize(records: Iterable[Mapping[str, Any]]) -> dict[str, SuiteMetrics]:
    """Per-suite metrics of one policy's records, ordered as the paper's tables then the rest."""
    groups = group_by_suite(records)
    return {s: suite_metrics(groups[s], s) for s in suite_order(groups)}


@dataclass(frozen=True)
class Average:
    """Mean over suites of GSR, TSR and nSG (as the paper's Avg column: a mean of suite values).

    ``complete`` says whether every suite of ``suites`` was present; the paper reports Avg only
    then. nSG is averaged over the suites where it is defined (``nsg_suites`` counts them).
    """

    suites: tuple[str, ...]
    present: tuple[str, ...]
    complete: bool
    gsr: float | None
    tsr: float | None
    nsg: float | None
    nsg_suites: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def avg_suites(suites: Iterable[str]) -> tuple[str, ...]:
    """The suites of the Avg column among ``suites`` run: the paper's six, or its Beyond Blocks six
    when only everyday-object suites were run; none when neither was (the Direct suites are
    controls and never enter Avg). The one rule that summaries, results.json and the leaderboard share."""
    run = tuple(suites)
    for group in (PAPER_SUITES, PAPER_OBJECT_SUITES):
        if any(s in group for s in run):
            return tuple(group)
    return ()


def average(metrics: Mapping[str, SuiteMetrics], suites: Sequence[str] | None = None) -> Average:
    """Avg column over ``suites`` (default: :func:`avg_suites` of those run), from those present.
    No suite to average over (a run of Direct controls only): every value None, not complete."""
    if suites is None:
        suites = avg_suites(metrics)
    present = [s for s in suites if s in metrics and metrics[s].n_episodes > 0]

    def mean(values: list[float]) -> float | None:
        return sum(values) / len(values) if values else None

    nsgs = [metrics[s].nsg.value for s in present if metrics[s].nsg.value is not None]
    return Average(
        suites=tuple(suites),
        present=tuple(present),
        complete=bool(suites) and len(present) == len(suites),
        gsr=mean([metrics[s].gsr.value for s in present]),
        tsr=mean([metrics[s].tsr.value for s in present]),
        nsg=mean(nsgs),
        nsg_suites=len(nsgs),
    )
