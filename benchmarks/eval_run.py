"""One `rsb eval` run, start to end: workers started once for every suite against once a suite, and the
throughput line against the records' own clock.

    python benchmarks/eval_run.py                      # both parts, 2 runs a tree, recorded
    python benchmarks/eval_run.py --repeats 1 --skip-line-check
    python benchmarks/eval_run.py --reference 955dfa3 --policy blind -n 4 --num-procs 2

Part 1: ``rsb eval POLICY --suites paper -n N --num-procs P -q`` (issue 63's run: blind, 6 suites x 4
episodes, 2 workers) on this checkout and on ``--reference`` (a commit whose workers started again for
every suite; checked out with ``git worktree`` into a temporary folder and run from there with
PYTHONPATH pointing at it), alternately (reference, this, this, reference, ...: a machine whose load
drifts weighs on both alike). Each run's wall time is the command's, start to exit; the records of the
two trees are compared too (without timings): the same episodes. ``$RSB_DATA_DIR`` must hold the
question data (the paper suites include GSM8K and MMLU-Pro ones).

Part 2: ``rsb eval random -o state --num-envs K --num-procs 1`` for K = 1 and 4: the env-steps/s of its
throughput line against env-steps over the steady wall time measured here: every episode's steps over the
time from the first episode's start (the moment its record appeared in episodes.jsonl, less its own
``wall_s``) to the moment the last one appeared.

Figures go to benchmarks/results/eval_run.json (recorded.py): the command, date, commit and machine
with its load. Timed on a loaded machine, the two trees' times still compare (same minutes, alternated).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from recorded import table, write

ROOT = Path(__file__).resolve().parents[1]
LINE = re.compile(r"throughput: start-up ([\d.]+) s, then ([\d,]+) env-steps/s \(([\d,]+) env-steps")


def _env(tree: Path) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(tree))


def _records(path: Path) -> list[dict]:
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    for r in rows:
        r.pop("wall_s", None)
        r.pop("settings", None)
    return sorted(rows, key=lambda r: (r["suite_id"], r["instruction_mode"], r["seed"]))


def _eval(tree: Path, argv: list[str], out: Path) -> dict:
    cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", *argv, "--out", str(out), "-q"]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=_env(tree), cwd=tree, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        sys.exit(f"{' '.join(cmd)} (in {tree}) failed ({res.returncode}):\n{res.stderr[-3000:]}")
    line = res.stdout.strip().splitlines()[-1]
    return {"wall_s": round(wall, 1), "line": line, "records": _records(out / "episodes.jsonl")}


def _worktree(commit: str, where: Path) -> Path:
    subprocess.run(["git", "worktree", "add", "--detach", "-q", str(where), commit], cwd=ROOT, check=True)
    return where


def one_start(reference: str, argv: list[str], repeats: int) -> dict:
    """Part 1: the same command on the reference tree and on this one, alternately."""
    with tempfile.TemporaryDirectory(prefix="rsb_eval_run_") as tmp:
        ref_tree = _worktree(reference, Path(tmp) / "reference")
        try:
            order = [("reference", ref_tree), ("this", ROOT)]
            runs: dict[str, list[dict]] = {"reference": [], "this": []}
            for r in range(repeats):
                for name, tree in (order if r % 2 == 0 else order[::-1]):
                    got = _eval(tree, argv, Path(tmp) / f"{name}-{r}")
                    runs[name].append(got)
                    print(f"{name:>9} run {r + 1}: {got['wall_s']:7.1f} s   {got['line']}", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(ref_tree)], cwd=ROOT, check=False)
    same = all(run["records"] == runs["reference"][0]["records"] for run in runs["reference"] + runs["this"])
    ref = statistics.median(run["wall_s"] for run in runs["reference"])
    new = statistics.median(run["wall_s"] for run in runs["this"])
    episodes = len(runs["this"][0]["records"])
    print(f"\nrsb eval {' '.join(argv)}: {episodes} episodes; median wall {ref:.1f} s at {reference}, {new:.1f} s "
          f"here: {ref / new:.2f}x; same records: {same}")
    return {"command": f"rsb eval {' '.join(argv)} -q", "reference": reference, "episodes": episodes,
            "wall_s": {name: [run["wall_s"] for run in rs] for name, rs in runs.items()},
            "median_wall_s": {"reference": ref, "this": new}, "speedup": round(ref / new, 2),
            "same_records": same, "lines": {name: [run["line"] for run in rs] for name, rs in runs.items()},
            "table": table(["tree", "runs (wall s)", "median wall s"],
                           [[f"{reference} (workers start a suite)", ", ".join(f"{run['wall_s']:.1f}" for run in
                                                                             runs["reference"]), f"{ref:.1f}"],
                            ["this (workers start once a run)", ", ".join(f"{run['wall_s']:.1f}" for run in
                                                                          runs["this"]), f"{new:.1f}"]])}


def _watched(argv: list[str], out: Path) -> tuple[str, list[float]]:
    """Runs ``rsb eval`` on this tree; its last line and the moment each record appeared."""
    cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", *argv, "--out", str(out), "-q"]
    proc = subprocess.Popen(cmd, env=_env(ROOT), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen: list[float] = []
    records = out / "episodes.jsonl"
    while proc.poll() is None:
        n = records.read_bytes().count(b"\n") if records.exists() else 0
        seen += [time.monotonic()] * (n - len(seen))
        time.sleep(0.005)
    stdout, stderr = proc.communicate()
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{stderr[-3000:]}")
    return stdout.strip().splitlines()[-1], seen


def line_check(envs: list[int], max_steps: int) -> dict:
    """Part 2: the throughput line's env-steps/s against the records' arrival, K envs a process."""
    rows, out = [], {}
    for k in envs:
        n = 8 * k if k > 1 else 8
        with tempfile.TemporaryDirectory(prefix="rsb_eval_line_") as tmp:
            line, seen = _watched(["random", "--suites", "RSB-Math-4", "-o", "state", "--max-steps", str(max_steps),
                                   "-n", str(n), "--num-envs", str(k), "--num-procs", "1"], Path(tmp))
            records = [json.loads(x) for x in (Path(tmp) / "episodes.jsonl").read_text().splitlines()]
        said = LINE.match(line)
        if not said:
            sys.exit(f"no throughput line: {line!r}")
        said_rate = float(said.group(2).replace(",", ""))
        measured = sum(int(r["steps"]) for r in records) / (seen[-1] - (seen[0] - float(records[0]["wall_s"])))
        print(f"K = {k}: {n} episodes; the line {said_rate:,.0f} env-steps/s, measured from the records "
              f"{measured:,.0f}: {said_rate / measured - 1:+.1%}   ({line})", flush=True)
        out[f"k{k}"] = {"episodes": n, "line_env_steps_per_s": said_rate, "measured_env_steps_per_s": round(measured),
                        "difference": round(said_rate / measured - 1, 4), "line": line}
        rows.append([str(k), str(n), f"{said_rate:,.0f}", f"{measured:,.0f}", f"{said_rate / measured - 1:+.1%}"])
    out["table"] = table(["K", "episodes", "the line (env-steps/s)", "records' clock (env-steps/s)", "difference"],
                         rows)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--reference", default="955dfa3", help="the commit to time against (default 955dfa3)")
    p.add_argument("--policy", default="blind")
    p.add_argument("--suites", nargs="+", default=["paper"])
    p.add_argument("-n", "--num-episodes", type=int, default=4)
    p.add_argument("--num-procs", type=int, default=2)
    p.add_argument("--repeats", type=int, default=2, help="runs a tree, alternated (default 2)")
    p.add_argument("--envs", type=int, nargs="+", default=[1, 4], help="part 2: K envs a process")
    p.add_argument("--max-steps", type=int, default=150, help="part 2: steps an episode")
    p.add_argument("--skip-one-start", action="store_true")
    p.add_argument("--skip-line-check", action="store_true")
    args = p.parse_args()
    if not os.environ.get("RSB_DATA_DIR") and not args.skip_one_start:
        print("note: RSB_DATA_DIR is not set: the paper suites' question data must be in the hub cache", flush=True)
    figures: dict = {"tables": {}}  # each part's figures, and its table for the pages (scripts/render_figures.py)
    if not args.skip_one_start:
        argv = [args.policy, "--suites", *args.suites, "-n", str(args.num_episodes), "--num-procs",
                str(args.num_procs)]
        figures["one_start"] = one_start(args.reference, argv, args.repeats)
    if not args.skip_line_check:
        figures["throughput_line"] = line_check(args.envs, args.max_steps)
    for part in ("one_start", "throughput_line"):
        if part in figures:
            figures["tables"][part] = figures[part].pop("table")
    write("eval_run", figures)


if __name__ == "__main__":
    main()
