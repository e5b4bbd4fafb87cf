"""Training speed of the diffusion-policy baseline: the real trainer, the experiment's settings
(docs/baselines.md), a few hundred iterations, seconds per iteration after the first 100, and
the wall time that projects to for a whole run.

    python benchmarks/dp_train_speed.py --demos X.h5 [--threads 2] [--iters 400] [--total 30000] [--no-language]
        [--record-as NAME]

Target (issue 11): a state policy trains within about an hour on 2 CPU cores.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from recorded import write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.baselines.diffusion_policy.train import main as train_main

EXPERIMENT = ["--prediction", "sample", "--unet-dims", "32", "64", "128", "--batch-size", "128", "--lr", "1e-3",
              "--warmup", "200"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demos", required=True, help="an `rsb generate` state file (train split)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--iters", type=int, default=400, help="iterations timed (the first 100 are warm-up)")
    ap.add_argument("--total", type=int, default=30_000, help="the run length the time is projected to")
    ap.add_argument("--no-language", action="store_true")
    ap.add_argument("--record-as", default="dp_train_speed", metavar="NAME",
                    help="the figures go to benchmarks/results/NAME.json (default dp_train_speed; docs/baselines.md's "
                         "one-thread figure: --threads 1 --record-as dp_train_speed_threads1)")
    args = ap.parse_args()
    if args.iters <= 100 or args.iters % 100:
        ap.error("--iters must be a multiple of 100 above 100")
    with tempfile.TemporaryDirectory() as tmp:
        train_main(["--demos", args.demos, "--out", tmp, *EXPERIMENT, "--threads", str(args.threads), "-q",
                    "--total-iters", str(args.total), "--stop-after", str(args.iters), "--save-every", str(10 ** 9),
                    *(["--no-language"] if args.no_language else [])])
        log = {r["step"]: r["train_s"] for r in map(json.loads, (Path(tmp) / "log.jsonl").read_text().splitlines())}
    per_iter = (log[args.iters] - log[100]) / (args.iters - 100)
    lang = "off" if args.no_language else "on"
    print(f"threads {args.threads}, language {lang}: {per_iter:.4f} s/iteration (iterations 100-{args.iters}); "
          f"{args.total:,} iterations = {per_iter * args.total / 60:.1f} min")
    write(args.record_as, {"threads": args.threads, "language": not args.no_language,
                           "s_per_iteration": round(per_iter, 4), "total_iterations": args.total,
                           "projected_min": round(per_iter * args.total / 60, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
