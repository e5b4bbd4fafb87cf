"""Seconds from a command to its message on a machine without the question data and without network.

Each command of tests/acceptance/test_offline.py runs in a fresh process with an empty hub cache and no
$RSB_DATA_DIR, once with a proxy on 127.0.0.1 that never answers (packets dropped: the worst case)
and once with RSB_OFFLINE=1; `rsb --help` is the start-up reference of the same run.

    python benchmarks/offline_latency.py

Target (issue 34): every command within 5 s (it was 3 min 7 s for `rsb stats`: the hub's retries).
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "helpers"))

from recorded import write  # noqa: E402  (benchmarks/recorded.py: the figures to benchmarks/results/)

from net_helpers import COMMANDS, no_data_env, silent_proxy_server  # noqa: E402


def seconds(args: list[str], env: dict[str, str]) -> tuple[float, int]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", *args], capture_output=True, env=env)
    return time.perf_counter() - t0, proc.returncode


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp, silent_proxy_server() as proxy:
        base = no_data_env(Path(tmp))
        dropped = {**base, "HTTPS_PROXY": proxy, "https_proxy": proxy}
        switch = {**base, "RSB_OFFLINE": "1"}
        print(f"{'command':<16}{'packets dropped s':>19}{'RSB_OFFLINE=1 s':>17}{'exit':>6}")
        help_s = (seconds(['--help'], dropped)[0], seconds(['--help'], switch)[0])
        print(f"{'rsb --help':<16}{help_s[0]:>19.2f}{help_s[1]:>17.2f}")
        figures = {"rsb --help": {"packets_dropped_s": round(help_s[0], 2), "offline_s": round(help_s[1], 2)}}
        for name, args in COMMANDS.items():
            args = [a.format(tmp=tmp) for a in args]
            (t_drop, rc), (t_off, _) = seconds(args, dropped), seconds(args, switch)
            print(f"{name:<16}{t_drop:>19.2f}{t_off:>17.2f}{rc:>6}")
            figures[name] = {"packets_dropped_s": round(t_drop, 2), "offline_s": round(t_off, 2), "exit": rc}
    timed = [v for k, v in figures.items() if k != "rsb --help"]
    figures["commands"] = {key: {"min": min(v[key] for v in timed), "max": max(v[key] for v in timed)}
                           for key in ("packets_dropped_s", "offline_s")}  # the ranges docs/semantic.md quotes
    write("offline_latency", figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
