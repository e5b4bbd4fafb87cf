"""`rsb plan`: how many episodes a claim needs, before the runs are made.

    rsb plan 0.30 0.40                         # tell a TSR of 30 % from 40 %
    rsb plan 30% 40% --variants 4 --icc 0.5    # counterfactual scenes: follow / switch
    rsb plan 0.3 0.4 --levels 3 --icc 0.3      # perturbed runs: each seed at 3 levels, a pooled claim

The numbers are ``evaluation/stats.py``'s (``plan_episodes``: Connor's formula, then the exact or
simulated power of the test ``rsb report --compare`` runs); docs/evaluation.md, "How many episodes a
claim needs".
"""
from __future__ import annotations

import argparse
import sys

DEFAULT_ICC = 0.5  # a scene's variants (a seed's levels): half alike; --icc 1 is the worst case


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "plan", help="the episodes needed to tell two rates apart (paired, unpaired, clustered)",
        description="Prints how many episodes each of two runs needs for a two-sided test at --alpha to tell "
                    "rate A from rate B with probability --power: paired (both runs on the same seeds, as "
                    "`rsb report --compare` tests them), unpaired (runs on other seeds), and with the clustering "
                    "of counterfactual scenes (--variants K episodes a scene) and of perturbed runs (--levels L "
                    "episodes a seed, a claim pooled over the levels) at intraclass correlation --icc. The "
                    "episode counts are checked against the test's own power: exact for independent episodes, "
                    "simulated (2,000 run pairs) for clustered ones.")
    p.add_argument("rate_a", metavar="A", help="the first rate: 0.3, 30%% or 30")
    p.add_argument("rate_b", metavar="B", help="the second rate, as A")
    p.add_argument("--alpha", type=float, default=0.05, help="two-sided significance level (default 0.05)")
    p.add_argument("--power", type=float, default=0.8, help="the chance of telling them apart (default 0.8)")
    p.add_argument("--variants", type=int, default=4, metavar="K",
                   help="counterfactual variants a scene (default 4; 1 leaves the line out)")
    p.add_argument("--levels", type=int, default=1, metavar="L",
                   help="perturbation levels each seed runs at, for a claim pooled over them (default 1: no line)")
    p.add_argument("--icc", type=float, default=DEFAULT_ICC,
                   help=f"how alike a scene's episodes are, 0 (independent) to 1 (all alike) (default {DEFAULT_ICC})")
    p.set_defaults(func=run_plan)


class PlanError(ValueError):
    """A rate or setting out of range: one line naming it."""


def parse_rate(text: str, name: str) -> float:
    """``"0.3"``, ``"30%"`` and ``"30"`` are 0.3; PlanError otherwise."""
    raw = text.strip()
    try:
        value = float(raw.rstrip("%"))
    except ValueError:
        raise PlanError(f"{name} {text!r} is not a rate: give 0.3, 30% or 30") from None
    if raw.endswith("%") or value > 1:
        value /= 100
    if not 0 <= value <= 1 or value != value:
        raise PlanError(f"{name} {text!r} is not a rate between 0 and 1 (0 % and 100 %)")
    return value


def _check(args: argparse.Namespace) -> tuple[float, float]:
    a, b = parse_rate(args.rate_a, "A"), parse_rate(args.rate_b, "B")
    if a == b:
        raise PlanError(f"A and B are both {100 * a:g} %: no number of episodes tells a rate from itself")
    if not 0 < args.alpha < 1 or not 0 < args.power < 1:
        raise PlanError(f"--alpha {args.alpha:g} and --power {args.power:g} must lie strictly between 0 and 1")
    if args.power <= args.alpha:
        raise PlanError(f"--power {args.power:g} must exceed --alpha {args.alpha:g}")
    if not 0 <= args.icc <= 1:
        raise PlanError(f"--icc {args.icc:g} must lie between 0 and 1")
    if args.variants < 1 or args.levels < 1:
        raise PlanError("--variants and --levels count episodes a scene: give 1 or more")
    return a, b


def plan_lines(a: float, b: float, alpha: float, power: float, variants: int, levels: int, icc: float) -> list[str]:
    """What `rsb plan` prints: one line a design."""
    from rsb_maniskill.evaluation.stats import plan_episodes, unpaired_sample_size

    paired = plan_episodes(a, b, alpha, power)
    lines = [f"To tell {100 * a:.1f} % from {100 * b:.1f} % (two-sided p < {alpha:g}, power {100 * power:g} %), "
             "each run needs:",
             f"- paired, the same seeds in both runs (`rsb report --compare`: McNemar's exact test): "
             f"{paired.episodes:,} episodes (power {100 * paired.power:.1f} %, exact)",
             f"- unpaired, on other seeds (two published rows): {unpaired_sample_size(a, b, alpha, power):,} episodes "
             "(two-proportion formula, a normal approximation: an exact test needs a few more)"]
    for size, what, unit in ((variants, "counterfactual scenes of {k} variants (follow, switch)", "scenes"),
                             (levels, "perturbed runs, each seed at {k} levels, a claim pooled over them", "seeds")):
        if size < 2:
            continue
        if icc == 0:
            clustered = plan_episodes(a, b, alpha, power)
            n_units = -(-clustered.episodes // size)
            lines.append(f"- {what.format(k=size)}, ICC 0: {n_units:,} {unit} = {n_units * size:,} episodes (as "
                         "independent ones)")
        else:
            clustered = plan_episodes(a, b, alpha, power, size=size, icc=icc)
            lines.append(f"- {what.format(k=size)}, ICC {icc:g}: {clustered.scenes:,} {unit} = {clustered.episodes:,} "
                         f"episodes (power {100 * clustered.power:.1f} %, simulated, the scene test)")
        if icc < 1:
            lines.append(f"  at ICC 1 (a {unit[:-1]}'s episodes all alike: it counts once): {paired.episodes:,} "
                         f"{unit} = {paired.episodes * size:,} episodes")
    lines.append("Assumed: the two runs' outcomes on an episode are independent (runs that fail the same hard "
                 "episodes need fewer); ICC: how alike a scene's episodes are (--icc; a counterfactual run's "
                 "summary.json gives the design effect it had, 1 + (K - 1) ICC).")
    return lines


def run_plan(args: argparse.Namespace) -> int:
    try:
        a, b = _check(args)
    except PlanError as err:
        print(f"rsb plan: error: {err}", file=sys.stderr)
        return 2
    print("\n".join(plan_lines(a, b, args.alpha, args.power, args.variants, args.levels, args.icc)))
    return 0
