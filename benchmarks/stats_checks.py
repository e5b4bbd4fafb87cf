"""The statistics' own checks, by simulation: where the clustered interval falls short of 95 %, and the
family-wise error of a page of many marks for identical policies.

    python benchmarks/stats_checks.py            # ~ a few minutes on 2 cores
    python benchmarks/stats_checks.py --quick    # fewer runs a cell (a smoke test)

Writes ``benchmarks/results/stats_checks.json`` (docs/evaluation.md renders its tables):

- ``coverage``: `stats.clustered_rate` over simulated runs, each cluster's success probability drawn from a
  beta law of mean ``rate`` and intraclass correlation 0.8 (the hardest the docs claim), 4 variants a scene
  or 1-5; every cell of the grid, the worst first (the docs list the 8 worst);
- ``family``: two identical policies compared on six suites (`rsb report --compare`'s GSR / TSR tests,
  500 episodes each) with and without Holm's correction, and five identical leaderboard rows (600 shared
  episodes) with Holm over the comparisons with the best alone and over every pair (the leaderboard's rule).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from recorded import table, write  # noqa: E402

from rsb_maniskill.evaluation.stats import ALPHA, clustered_rate, holm, holm_marks, sign_flip_pvalues  # noqa: E402

RATES = (0.01, 0.05, 0.2, 0.5, 0.8, 0.95)
SCENES = (10, 20, 30, 50)
SIZES = {"4": (4,), "1-5": (1, 2, 3, 4, 5)}
ICC = 0.8
WORST = 8  # the cells the docs list, the worst first


def coverage(rate: float, clusters: int, sizes: tuple[int, ...], sims: int, seed: int) -> float:
    rng = np.random.default_rng(seed)
    s = 1 / ICC - 1
    held = 0
    for _ in range(sims):
        m = rng.choice(sizes, clusters)
        q = np.repeat(rng.beta(rate * s, (1 - rate) * s, clusters), m)
        r = clustered_rate(rng.random(m.sum()) < q, np.repeat(np.arange(clusters), m))
        held += r.low <= rate <= r.high
    return held / sims


def compare_family(sims: int, seed: int) -> tuple[float, float]:
    rng = np.random.default_rng(seed)
    p = []
    for _ in range(6):
        g = rng.random((2, sims, 500)) < 0.7
        ok = g & (rng.random((2, sims, 500)) < 0.4 / 0.7)
        p += [sign_flip_pvalues(x[1].astype(int) - x[0].astype(int)) for x in (g, ok)]
    p = np.array(p).T
    raw = float(np.mean((p < ALPHA).any(axis=1)))
    family = float(np.mean([any(m.significant for m in holm_marks([(x, None, None) for x in row])) for row in p]))
    return raw, family


def leaderboard_family(sims: int, seed: int, rows: int = 5) -> tuple[float, float]:
    from rsb_maniskill.reporting.leaderboard import differences_from_best

    rng = np.random.default_rng(seed)
    won = rng.random((sims, rows, 600)) < 0.45
    pairs = [(i, j) for i in range(rows) for j in range(i + 1, rows)]
    p = np.stack([sign_flip_pvalues(won[:, j].astype(int) - won[:, i].astype(int)) for i, j in pairs], 1)
    best = won.sum(2).argmax(1)
    best_only = family = 0
    for s in range(sims):
        found = differences_from_best(dict(zip(pairs, p[s])), int(best[s]))
        family += any(adjusted < ALPHA for _, adjusted in found.values())
        best_only += any(a < ALPHA for a in holm([raw for raw, _ in found.values()]))
    return best_only / sims, family / sims


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="200 runs a coverage cell, 1,000 comparisons")
    args = ap.parse_args()
    sims, fam = (200, 1000) if args.quick else (2000, 10000)
    start = time.time()
    cells = []
    for sizes_name, sizes in SIZES.items():
        for clusters in SCENES:
            for i, rate in enumerate(RATES):
                cells.append((coverage(rate, clusters, sizes, sims, seed=1000 * clusters + i), clusters,
                              sizes_name, rate))
    cells.sort()
    se = np.sqrt(0.95 * 0.05 / sims)
    rows = [[f"{clusters}", sizes_name, f"{100 * rate:g} %", f"{100 * cov:.1f} %"]
            for cov, clusters, sizes_name, rate in cells[:WORST]]
    raw, holm_compare = compare_family(fam, seed=1)
    best_only, pairs = leaderboard_family(fam, seed=2)
    se_f = np.sqrt(0.05 * 0.95 / fam)
    figures = {
        "coverage_runs_a_cell": sims, "coverage_se_points": round(100 * se, 2), "icc": ICC,
        "coverage_cells": len(cells), "coverage_worst": round(100 * cells[0][0], 1),
        "coverage_best": round(100 * cells[-1][0], 1),
        "coverage_below_93": sum(cov < 0.93 for cov, *_ in cells),
        "coverage_after_worst": round(100 * cells[WORST][0], 1),
        "all_cells": [{"scenes": c, "sizes": s, "rate": r, "coverage": round(v, 4)} for v, c, s, r in cells],
        "family_runs": fam, "family_se_points": round(100 * se_f, 2),
        "compare_unadjusted": round(100 * raw, 1), "compare_holm": round(100 * holm_compare, 1),
        "leaderboard_best_only": round(100 * best_only, 1), "leaderboard_all_pairs": round(100 * pairs, 1),
        "tables": {
            "coverage": table(["Scenes", "Variants a scene", "Rate", "Coverage"], rows, "rlrr"),
            "family": table(["Page", "Rule", "Some mark, identical policies"], [
                ["`--compare`, six suites, GSR + TSR (12 tests)", "none (each at 0.05)", f"{100 * raw:.1f} %"],
                ["", "Holm over the table", f"{100 * holm_compare:.1f} %"],
                ["`rsb leaderboard`, five rows", "Holm over the 4 comparisons with the best",
                 f"{100 * best_only:.1f} %"],
                ["", "Holm over every pair of rows (10 tests)", f"{100 * pairs:.1f} %"],
            ], "llr"),
        },
        "seconds": round(time.time() - start, 1),
    }
    for cov, clusters, sizes_name, rate in cells[:8]:
        print(f"coverage {100 * cov:5.1f} %  scenes {clusters:3d}  variants {sizes_name:4s}  rate {rate:g}")
    print(f"compare: unadjusted {100 * raw:.1f} %, Holm {100 * holm_compare:.1f} %; leaderboard: best only "
          f"{100 * best_only:.1f} %, all pairs {100 * pairs:.1f} % ({fam:,} runs)")
    write("stats_checks", figures, notes="ICC 0.8 beta-law clusters; identical policies for the family-wise error")


if __name__ == "__main__":
    main()
