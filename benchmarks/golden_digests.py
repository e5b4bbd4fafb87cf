"""Time of `rsb verify`'s work: the pinned-episode digests of every suite (16 suites x 1,000
episodes: the 500 protocol evaluation and the first 500 training episodes, layout included).

    python benchmarks/golden_digests.py [--data-dir DIR]

Printed: loading the question pools (once a process), then, on the loaded pools, sampling the
same episodes alone (the reference: what any run of them costs) and digesting them (sampling,
layouts without the simulator, canonical JSON, SHA-256). Target (issue 34): fast enough for a
test and for `rsb verify`: seconds, not minutes.
"""
from __future__ import annotations

import argparse
import time

from recorded import write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.audit import golden
from rsb_maniskill.objects.family import split_env_id
from rsb_maniskill.semantic import EpisodeSampler
from rsb_maniskill.semantic.suites import SOURCES


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data-dir", default=None, help="GSM8K / MMLU-Pro (default $RSB_DATA_DIR or the hub cache)")
    args = ap.parse_args()
    env_ids = golden.all_env_ids()
    sets = golden.episode_sets()
    t0 = time.perf_counter()
    for source in SOURCES.values():
        if not source.direct:
            for split in ("train", "test"):
                EpisodeSampler(f"RSB-{source.name}-4", split, data_dir=args.data_dir)
    t1 = time.perf_counter()
    n = 0
    for eid in env_ids:
        suite_id, targets = split_env_id(eid)
        for cfg in sets.values():
            sampler = EpisodeSampler(suite_id, cfg["split"], cfg["instructions"], cfg["color_map"], args.data_dir,
                                     targets=targets)
            for seed in range(cfg["first_seed"], cfg["first_seed"] + cfg["episodes"]):
                sampler.episode(seed)
                n += 1
    t2 = time.perf_counter()
    golden.compute(env_ids, args.data_dir)
    t3 = time.perf_counter()
    print(f"{'step':<48}{'s':>8}")
    print(f"{'load the question pools (once a process)':<48}{t1 - t0:>8.2f}")
    print(f"{f'sample {n:,} episodes (reference)':<48}{t2 - t1:>8.2f}")
    print(f"{f'digest {n:,} episodes ({len(env_ids)} suites, with layouts)':<48}{t3 - t2:>8.2f}")
    print(f"{'rsb verify, all suites (pools + digests)':<48}{t1 - t0 + t3 - t2:>8.2f}")
    write("golden_digests", {"episodes": n, "suites": len(env_ids), "load_pools_s": round(t1 - t0, 2),
                             "sample_s": round(t2 - t1, 2), "digest_s": round(t3 - t2, 2),
                             "verify_work_s": round(t1 - t0 + t3 - t2, 2)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
