"""``rsb verify``: does this install give the pinned episodes of this benchmark version? (``audit/golden.py``)."""
from __future__ import annotations

import argparse
import sys
import time

from rsb_maniskill.audit.golden import GOLDEN_FILE, differences, load, suite_digests


def register(subparsers: argparse._SubParsersAction) -> None:
    from rsb_maniskill.env_ids import add_suites_argument

    p = subparsers.add_parser(
        "verify", help="does this install give the pinned episodes of this benchmark version?",
        description="Recomputes every suite's protocol evaluation episodes, their counterfactual variants and the "
                    "first training episodes (questions, options, instructions, candidates, layout) and compares "
                    "their digests with "
                    "the ones pinned for this benchmark version. Exit status 1 when a suite differs or could "
                    "not be checked. No simulator: it samples the episodes and builds no env.")
    add_suites_argument(p, default=["all", "all-objects"], positional=True)
    p.add_argument("--data-dir", default=None,
                   help="GSM8K / MMLU-Pro directory (else $RSB_DATA_DIR, else the hub cache)")
    p.set_defaults(func=cmd_verify)


def cmd_verify(args: argparse.Namespace) -> int:
    from rsb_maniskill.semantic.errors import SemanticError
    from rsb_maniskill.version import BENCHMARK_VERSION, benchmark_label

    t0 = time.perf_counter()
    pinned = load()
    if pinned["benchmark_version"] != BENCHMARK_VERSION:
        print(f"rsb verify: error: {GOLDEN_FILE} pins {pinned['benchmark']}, the code is {benchmark_label()}: "
              "reinstall the package", file=sys.stderr)
        return 1
    differ, unchecked, missing = [], [], None
    for eid in args.suites:
        try:
            diff = differences({eid: suite_digests(eid, args.data_dir)}, pinned).get(eid)
        except SemanticError as err:
            missing = missing or str(err)
            unchecked.append(eid)
            print(f"{eid:<26} not checked (question data missing)")
            continue
        if diff:
            differ.append(eid)
            print(f"{eid:<26} DIFFERS from {pinned['benchmark']} ({', '.join(diff)} episodes)")
        else:
            print(f"{eid:<26} ok")
    if missing:
        print(f"rsb verify: {missing}", file=sys.stderr)
    took = f"{len(args.suites)} suite(s), {time.perf_counter() - t0:.1f} s"
    if differ:
        print(f"this install does NOT give the episodes of {pinned['benchmark']}: {', '.join(differ)} ({took})")
    elif unchecked:
        print(f"NOT verified: {len(unchecked)} suite(s) could not be checked (their question data is missing; "
              f"`rsb data` says how to fetch it); the {len(args.suites) - len(unchecked)} checked give "
              f"{pinned['benchmark']}'s episodes ({took})")
    else:
        print(f"this install gives the episodes of {pinned['benchmark']} ({took})")
    status = 1 if differ or unchecked else 0
    return status
