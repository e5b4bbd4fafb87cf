"""Records made by hand: a policy's outcomes on a suite, for the report tests."""
from __future__ import annotations


def records(policy, suite, n_success, n_wrong, n_none, mode="normal"):
    """``n_success`` correct placements, ``n_wrong`` wrong grasps, ``n_none`` no grasp (seeds 0, 1, ...)."""
    out = []
    for i in range(n_success + n_wrong + n_none):
        ok, grasped = i < n_success, i < n_success + n_wrong
        out.append({"policy": policy, "suite_id": suite, "seed": i, "instruction_mode": mode,
                    "grasped_any": grasped, "grasped_correct": ok, "placed_correct": ok, "placed_wrong": False,
                    "success": ok})
    return out
