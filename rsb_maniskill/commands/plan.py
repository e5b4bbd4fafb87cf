"""`rsb plan`: how many episodes a claim needs, before the runs are made.

    rsb plan 0.30 0.40                         # tell a TSR of 30 % from 40 %
    rsb plan 30% 40% --variants 4 --icc 0.5    # counterfactual scenes: follow

Every count is the fewest at which the test the reports run reaches the power asked for, searched
from both sides of a formula's answer (``evaluation/stats.py``: ``plan_paired``, ``plan_unpaired``,
``plan_scenes``): McNemar's exact test and the two-proportion z test computed exactly, the scene
test simulated; docs/evaluation.md, "How many episodes a claim needs".
"""
from __future__ import annotations

import argparse
import math
import sys

DEFAULT_ICC = 0.5  # a scene's variants: half alike; --icc 1 is the worst case (a scene counts once)
ALPHA_RANGE, POWER_RANGE = (0.0001, 0.2), (0.5, 0.99)
MAX_VARIANTS = 10  # a counterfactual scene has at most N variants, and N is 4 or 10


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "plan", help="the episodes needed to tell two rates apart (paired, unpaired, counterfactual scenes)",
        description="Prints how many episodes each of two runs needs for a two-sided test at --alpha to tell "
                    "rate A from rate B with probability --power, for the test the reports run: paired (both runs "
                    "on the same seeds, McNemar's exact test, as `rsb report --compare` runs it), unpaired (runs "
                    "on other seeds: the two-proportion z test of `rsb leaderboard` and of --compare on results.json "
                    "files), and counterfactual scenes of --variants K (follow over the K - 1 changed variants, the "
                    "scene test) at intraclass correlation --icc. Exact powers where they can be computed; the "
                    "scene test's simulated (10,000 run pairs, the count printed only where its estimate less 3 "
                    "standard errors reaches --power). Give both rates as fractions (0.3 0.4) or both as percents "
                    "(30% 40%).")
    p.add_argument("rate_a", metavar="A", help="the first rate: 0.3, or 30%% (then B in percents too)")
    p.add_argument("rate_b", metavar="B", help="the second rate, in A's unit")
    p.add_argument("--alpha", type=float, default=0.05,
                   help=f"two-sided significance level, {ALPHA_RANGE[0]:g} to {ALPHA_RANGE[1]:g} (default 0.05)")
    p.add_argument("--power", type=float, default=0.8,
                   help=f"the chance of telling them apart, {POWER_RANGE[0]:g} to {POWER_RANGE[1]:g} (default 0.8)")
    p.add_argument("--variants", type=int, default=4, metavar="K",
                   help=f"counterfactual variants a scene, 1 to {MAX_VARIANTS} (default 4; 1 leaves the line out)")
    p.add_argument("--icc", type=float, default=DEFAULT_ICC,
                   help="how alike a scene's variants are, 0 (independent) to 1 (all alike: the worst case) "
                        f"(default {DEFAULT_ICC})")
    p.set_defaults(func=run_plan)


class PlanError(ValueError):
    """A rate or setting out of range: one line naming it."""


def _number(text: str, name: str) -> tuple[float, bool]:
    raw = text.strip()
    try:
        value = float(raw.removesuffix("%"))
    except ValueError:
        raise PlanError(f"{name} {text!r} is not a rate: give 0.3 or 30%") from None
    if not math.isfinite(value):
        raise PlanError(f"{name} {text!r} is not a rate: give 0.3 or 30%")
    return value, raw.endswith("%")


def parse_rates(a_text: str, b_text: str) -> tuple[float, float]:
    """Two rates in one unit: both fractions (``0.3 0.4``) or both percents (``30% 40%``, or ``30 40``:
    a bare number above 1 is a percent, and makes the command's unit percents). A bare number in
    (0, 1] beside a percent is read both ways by someone: PlanError, as is a rate out of range."""
    (a, a_pct), (b, b_pct) = _number(a_text, "A"), _number(b_text, "B")
    percents = a_pct or b_pct or a > 1 or b > 1
    if percents:
        for text, value, marked in ((a_text, a, a_pct), (b_text, b, b_pct)):
            if not marked and 0 < value <= 1:
                raise PlanError(f"rates in one unit: {a_text!r} and {b_text!r} mix a fraction with a percent "
                                f"({text} could be {100 * value:g} % or {value:g} %); give both as fractions (0.3 "
                                "0.4) or both as percents (30% 40%)")
    for name, text, value in (("A", a_text, a), ("B", b_text, b)):
        top = 100 if percents else 1
        if not 0 <= value <= top:
            raise PlanError(f"{name} {text!r} is not a rate between 0 and 1 (0 % and 100 %)")
    return (a / 100, b / 100) if percents else (a, b)


def _check(args: argparse.Namespace) -> tuple[float, float]:
    a, b = parse_rates(args.rate_a, args.rate_b)
    if a == b:
        raise PlanError(f"A and B are both {100 * a:g} %: no number of episodes tells a rate from itself")
    if not ALPHA_RANGE[0] <= args.alpha <= ALPHA_RANGE[1]:
        raise PlanError(f"--alpha {args.alpha:g}: give a significance level from {ALPHA_RANGE[0]:g} to "
                        f"{ALPHA_RANGE[1]:g}")
    if not POWER_RANGE[0] <= args.power <= POWER_RANGE[1]:
        raise PlanError(f"--power {args.power:g}: give a power from {POWER_RANGE[0]:g} to {POWER_RANGE[1]:g}")
    if not 0 <= args.icc <= 1:
        raise PlanError(f"--icc {args.icc:g} must lie between 0 and 1")
    if not 1 <= args.variants <= MAX_VARIANTS:
        raise PlanError(f"--variants {args.variants}: a counterfactual scene has 1 to {MAX_VARIANTS} variants")
    return a, b


def _episodes(plan, unit: str = "episodes") -> str:
    """``"377 episodes"``, or "more than 1,000,000 episodes" past the cap."""
    from rsb_maniskill.evaluation.stats import MAX_EPISODES

    if plan.scenes is None:
        return f"more than {MAX_EPISODES:,} episodes (a difference this small is not worth planning)"
    if plan.size == 1:
        return f"{plan.episodes:,} {unit}"
    return f"{plan.scenes:,} scenes = {plan.episodes:,} episodes"


def _power(plan, sims: int) -> str:
    if plan.scenes is None:
        return ""
    how = {"exact": "exact", "normal approximation": "the scene test's normal approximation (many scenes)",
           "simulated": f"simulated over {sims:,} run pairs, less 3 standard errors still {100 * 0.8:g} % or more"}
    return f" (power {100 * plan.power:.1f} %, {how[plan.how]})"


def plan_lines(a: float, b: float, alpha: float = 0.05, power: float = 0.8, variants: int = 4,
               icc: float = DEFAULT_ICC) -> list[str]:
    """What `rsb plan` prints: one line a design."""
    from rsb_maniskill.evaluation.stats import PLAN_SIMS, plan_paired, plan_scenes, plan_unpaired

    paired, unpaired = plan_paired(a, b, alpha, power), plan_unpaired(a, b, alpha, power)
    lines = [f"To tell {100 * a:.1f} % from {100 * b:.1f} % (two-sided p < {alpha:g}, power {100 * power:g} %), "
             "each run needs:",
             f"- paired, the same seeds in both runs (`rsb report --compare`: McNemar's exact test): "
             f"{_episodes(paired)}{_power(paired, PLAN_SIMS)}",
             f"- unpaired, on other seeds (`rsb leaderboard`, --compare of results.json files: the two-proportion z "
             f"test): {_episodes(unpaired)}{_power(unpaired, PLAN_SIMS)}"]
    if variants > 1:
        scenes = plan_scenes(a, b, alpha, power, size=variants, counted=variants - 1, icc=icc)
        lines.append(f"- counterfactual scenes of {variants} variants, follow over the {variants - 1} changed ones "
                     f"(all grasped), ICC {icc:g}: {_episodes(scenes)}{_power(scenes, PLAN_SIMS)}")
        if icc < 1 and variants > 2:
            worst = plan_scenes(a, b, alpha, power, size=variants, counted=variants - 1, icc=1.0)
            lines.append(f"  at ICC 1 (a scene's variants all alike: it counts once): {_episodes(worst)}"
                         f"{_power(worst, PLAN_SIMS)}")
    lines.append("Assumed: the two runs' outcomes on an episode independent (runs that fail the same hard episodes "
                 "need fewer); follow: every changed variant grasped (fewer grasps need more scenes); ICC: how alike "
                 "a scene's variants are (--icc; a counterfactual run's summary.json gives the design effect it had, "
                 "1 + (K - 2) ICC over its K - 1 changed variants).")
    return lines


def run_plan(args: argparse.Namespace) -> int:
    try:
        a, b = _check(args)
    except PlanError as err:
        print(f"rsb plan: error: {err}", file=sys.stderr)
        return 2
    print("\n".join(plan_lines(a, b, args.alpha, args.power, args.variants, args.icc)))
    return 0
