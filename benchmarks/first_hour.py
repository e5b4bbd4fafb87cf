"""What a new user waits for, as the README tells them: `make demo` on a fresh clone, the set-up again once
everything is installed, `rsb verify` and `rsb doctor`.

    python benchmarks/first_hour.py [--no-fresh] [--data-dir DIR]

Fresh (the default): the checkout's committed HEAD is cloned into a temporary folder and `make setup`
runs there into a new venv with an empty uv cache (pip's own index settings as this machine has them:
a wheel mirror makes it faster than a download), then `make setup` again (everything installed), then
`rsb demo` of that venv: `make demo` fresh is the first set-up plus the demo. System packages
(Mesa's lavapipe, Chromium) are whatever the machine has: their apt time is not counted where they
are installed. `--no-fresh` times only `rsb verify`, `rsb doctor` and `rsb demo` of this checkout's venv.
`rsb verify` checks every suite's pinned episodes and reads the question data (`--data-dir`, else
$RSB_DATA_DIR). Each command runs once: on a shared machine read the load in the recorded file.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from recorded import ROOT, table, write  # benchmarks/recorded.py: the figures to benchmarks/results/


def timed(cmd: list[str], cwd: Path, env: dict[str, str]) -> tuple[float, int]:
    t = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    print(f"{' '.join(cmd)}: {wall:.1f} s, exit {done.returncode}", flush=True)
    if done.returncode not in (0, 1):  # rsb doctor exits 1 when something is missing: still a timing
        sys.exit(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return wall, done.returncode


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-fresh", action="store_true", help="skip the fresh clone's set-up")
    ap.add_argument("--data-dir", default=os.environ.get("RSB_DATA_DIR"), help="question data for rsb verify")
    args = ap.parse_args()
    env = {**os.environ}
    if args.data_dir:
        env["RSB_DATA_DIR"] = args.data_dir
    figures: dict[str, float | int] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        if args.no_fresh:
            rsb, cwd = str(ROOT / ".venv" / "bin" / "rsb"), ROOT
        else:
            clone = tmp_path / "clone"
            subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
            fresh_env = {**env, "UV_CACHE_DIR": str(tmp_path / "uv-cache")}
            for var in ("VIRTUAL_ENV", "PYTHONPATH"):  # the clone's own venv and code, as a new user has them
                fresh_env.pop(var, None)
            figures["setup_fresh_s"], _ = timed(["make", "setup"], clone, fresh_env)
            figures["setup_installed_s"], _ = timed(["make", "setup"], clone, fresh_env)
            rsb, cwd = str(clone / ".venv" / "bin" / "rsb"), clone
            rows += [["`make setup` on a fresh clone (new venv, empty uv cache)", f"{figures['setup_fresh_s']:.0f}"],
                     ["`make setup` again (everything installed)", f"{figures['setup_installed_s']:.0f}"]]
        env = fresh_env if not args.no_fresh else env
        figures["demo_s"], _ = timed([rsb, "demo", "--out", str(tmp_path / "demo")], cwd, env)
        rows.append(["`rsb demo` (what `make demo` runs after the set-up)", f"{figures['demo_s']:.0f}"])
        if not args.no_fresh:
            figures["make_demo_fresh_s"] = figures["setup_fresh_s"] + figures["demo_s"]
            rows.append(["`make demo` on a fresh clone (the two above)", f"{figures['make_demo_fresh_s']:.0f}"])
        figures["verify_s"], figures["verify_exit"] = timed([rsb, "verify"], cwd, env)
        rows.append(["`rsb verify` (every suite's pinned episodes)", f"{figures['verify_s']:.0f}"])
        figures["doctor_s"], figures["doctor_exit"] = timed([rsb, "doctor"], cwd, env)
        rows.append(["`rsb doctor`", f"{figures['doctor_s']:.0f}"])
        figures = {k: round(v, 1) for k, v in figures.items()}
        write("first_hour", {**figures, "fresh": not args.no_fresh,  # before the clean-up (minutes for a venv)
                             "table": table(["command", "wall s"], rows)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
