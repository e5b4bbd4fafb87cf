"""Semantic engine speed: ms per episode spec from a loaded pool (per suite) and the GSM8K /
MMLU load times. Usage: python benchmarks/bench_semantic.py [--data-dir DIR] [-n N]

Targets (issue 3): well under 1 ms per spec; loading GSM8K and MMLU under 2 s.
"""
from __future__ import annotations

import argparse
import time

from recorded import write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.semantic import SUITE_IDS, DataNotFoundError, EpisodeSampler, clear_cache, parse_suite_id
from rsb_maniskill.semantic.gsm8k import gsm8k_pool
from rsb_maniskill.semantic.pools import get_pool


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data-dir", default=None, help="else $RSB_DATA_DIR, else hub cache")
    ap.add_argument("-n", "--num-episodes", dest="episodes", type=int, default=2000)
    args = ap.parse_args()

    clear_cache()
    loads: dict[str, float] = {}
    spec_ms: dict[str, float] = {}
    try:
        t = time.perf_counter()
        for split in ("train", "test"):
            gsm8k_pool(split, args.data_dir)
        t_gsm = time.perf_counter() - t
        t = time.perf_counter()
        for split in ("train", "test"):
            get_pool("General", split, args.data_dir)
        t_gen = time.perf_counter() - t
        loads.update(gsm8k_s=round(t_gsm, 3), general_s=round(t_gen, 3))
        print(f"load GSM8K (train+test, parse + build questions): {t_gsm:.3f} s")
        print(f"load MMLU + commonsense (General train+test pools): {t_gen:.3f} s")
    except DataNotFoundError as err:
        print(f"GSM8K/MMLU not available, only built-in suites measured: {err}")

    print(f"{'suite':<18}{'split':<7}{'ms/spec':>9}   ({args.episodes} episodes, pool loaded)")
    for sid in SUITE_IDS:
        suite, _ = parse_suite_id(sid)
        for split in ("train", "test"):
            try:
                s = EpisodeSampler(sid, split, data_dir=args.data_dir)
            except DataNotFoundError:
                continue
            s.sample(0)  # warm lazily built per-pool tables
            t = time.perf_counter()
            for seed in range(args.episodes):
                s.sample(seed)
            ms = (time.perf_counter() - t) / args.episodes * 1e3
            print(f"{sid:<18}{split:<7}{ms:>9.3f}")
            spec_ms[f"{sid} {split}"] = round(ms, 4)
    spec_range = {"min": min(spec_ms.values()), "max": max(spec_ms.values())} if spec_ms else None
    write("bench_semantic", {"load": loads, "ms_per_spec": spec_ms, "ms_per_spec_range": spec_range,
                             "episodes": args.episodes})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
