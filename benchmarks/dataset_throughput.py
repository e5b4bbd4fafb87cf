"""Throughput of `rsb dataset build`, and the projected time of the paper's six training sets.

One run builds the same questions of RSB-Math-4 (three cameras at 320x240 unless --camera-size says
otherwise) three times, each in a fresh Python process so that lavapipe reads its thread setting
anew:

- 1 process, lavapipe's own threading (its default: one raster thread per CPU);
- 1 process, T raster threads (T = CPUs / 2: one worker's share of the cores);
- 2 worker processes, T raster threads each (what `rsb dataset build --num-procs 2` does by itself
  on software rendering: `LP_NUM_THREADS` = its share of the CPUs, unless you set it).

It prints demos/min, rendered frames/s and the CPU cores each run kept busy, the worker scaling (2
processes / 1 process, both at T threads a process) and the absolute gain of 2 processes over one
process with lavapipe's own threads. It then times the expert alone on the same questions to split a
demo's cost into the expert's share and the rendering + writing share, and projects the wall time of
the six paper training sets (every training question of each suite, pools as the code has them) on
this machine (on a GPU rendering does not scale with processes: docs/gpu.md's table of GPU figures
projects it). The figures go to `benchmarks/results/dataset_throughput.json`. Run it on an
otherwise idle machine:

    python benchmarks/dataset_throughput.py --questions 16
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

PAPER_POOLS_FALLBACK = {"Math": 500, "HardMath": 7473, "General": 4380}  # without question data here


def _pools(data_dir: str | None) -> tuple[dict[str, int], str]:
    from rsb_maniskill.semantic import EpisodeSampler

    try:
        return ({s: EpisodeSampler(f"RSB-{s}-4", split="train", data_dir=data_dir).num_questions
                 for s in ("Math", "HardMath", "General")}, "from the question data")
    except Exception as err:  # noqa: BLE001
        return PAPER_POOLS_FALLBACK, f"fallback figures ({type(err).__name__}: no question data here)"


def _cpu_s() -> float:
    """CPU seconds used so far by this process and its finished children."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _build(out: Path, procs: int, n: int, size: tuple[int, int]) -> tuple[float, dict, float]:
    """Wall seconds, the suite's summary, and the CPU cores the build kept busy on average."""
    from rsb_maniskill.export.build import BuildConfig, build_datasets

    t0, c0 = time.perf_counter(), _cpu_s()
    s = build_datasets(BuildConfig(suites=["RSB-Math-4"], out=str(out), questions=f"0:{n}",
                                   shard_size=max(1, n // 4), num_procs=procs, progress=False,
                                   env_kwargs={"camera_size": size}))
    wall = time.perf_counter() - t0
    return wall, s[0], (_cpu_s() - c0) / wall


def _build_in_child(out: Path, procs: int, threads: int | None, n: int, size: tuple[int, int]) -> dict:
    """:func:`_build` in a fresh process with ``LP_NUM_THREADS`` = ``threads`` (None: lavapipe's
    default; with ``procs`` > 1 the build gives each worker its share); returns its figures."""
    env = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"}
    if threads is not None and procs == 1:
        env["LP_NUM_THREADS"] = str(threads)
    cmd = [sys.executable, __file__, "--_child", json.dumps([str(out), procs, n, list(size)])]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"build with {procs} process(es) failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _child(spec: str) -> None:
    out, procs, n, size = json.loads(spec)
    wall, s, cores = _build(Path(out), procs, n, tuple(size))
    print(json.dumps({"wall": wall, "episodes": s["episodes"], "frames": s["frames"], "cores": cores}))


def _expert_only(out: Path, n: int) -> float:
    from rsb_maniskill.motionplan.generate import GenerateConfig, generate
    from rsb_maniskill.parallel.pool import InProcess

    t0 = time.perf_counter()
    generate(GenerateConfig(env_id="RSB-Math-4", out=str(out), questions=f"0:{n}", progress=False), InProcess())
    return time.perf_counter() - t0


def _encode_per_frame(size: tuple[int, int], tmp: Path) -> float:
    """Seconds to encode one three-camera frame (the writer's codec), on smooth synthetic images."""
    import numpy as np

    from rsb_maniskill.export.lerobot import _write_video

    w, h = size
    ramp = np.linspace(0, 255, w, dtype=np.float32)[None, :, None]
    frames = np.stack([np.broadcast_to(ramp + 8 * t, (h, w, 3)) % 255 for t in range(120)]).astype(np.uint8)
    t0 = time.perf_counter()
    for cam in range(3):
        _write_video(tmp / f"cam{cam}.mp4", frames, 25)
    return (time.perf_counter() - t0) / len(frames)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--questions", type=int, default=8, help="questions (demos) per run (default 8)")
    ap.add_argument("--camera-size", default="320x240", help="WxH of the three cameras (default 320x240)")
    ap.add_argument("--data-dir", default=os.environ.get("RSB_DATA_DIR"))
    ap.add_argument("--_child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")  # pool sizes: local data or the fallback, no network waits
    if args._child:
        return _child(args._child)
    from rsb_maniskill.sim.render import lavapipe_share, software_rendering

    size = tuple(int(v) for v in args.camera_size.split("x"))
    share = lavapipe_share(2)  # raster threads of each of 2 workers
    load_before = os.getloadavg()[0]  # read before the runs: other work on the machine skews every figure
    tmp = Path(tempfile.mkdtemp(prefix="rsb-dataset-bench-"))
    configs = {  # label -> (processes, lavapipe threads a process; None: lavapipe's default)
        "1 process, lavapipe's default threads": (1, None),
        f"1 process, {share} lavapipe thread(s)": (1, share),
        f"2 processes, {share} lavapipe thread(s) each": (2, share),
    }
    try:
        runs = {label: _build_in_child(tmp / f"run{i}", procs, threads, args.questions, size)
                for i, (label, (procs, threads)) in enumerate(configs.items())}
        expert_s = _expert_only(tmp / "expert", args.questions)
        encode_per_frame = _encode_per_frame(size, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"machine: {os.cpu_count()} CPUs, load before: {load_before:.2f}; cameras 3 x {size[0]}x{size[1]}; "
          f"renderer: {'lavapipe (software)' if software_rendering() else 'GPU Vulkan driver'}")
    for label, r in runs.items():
        print(f"{label}: {r['episodes']} demos, {r['frames']} frames in {r['wall']:.1f} s -> "
              f"{60 * r['episodes'] / r['wall']:.1f} demos/min, {r['frames'] / r['wall']:.1f} rendered frames/s, "
              f"{r['cores']:.2f} CPU cores busy on average")
    fps = [r["frames"] / r["wall"] for r in runs.values()]
    print(f"worker scaling, frames/s of 2 processes / 1 process at {share} thread(s) each: {fps[2] / fps[1]:.2f}x "
          "(target >= 1.8x)")
    print(f"2 processes at {share} thread(s) each / 1 process with lavapipe's default threads: {fps[2] / fps[0]:.2f}x")

    first = next(iter(runs.values()))
    wall1, eps, frames = first["wall"], first["episodes"], first["frames"]
    frames_per_demo = frames / eps
    expert_per_demo = expert_s / eps
    render_per_frame = max(wall1 - expert_s, 0.0) / frames  # render + encode + write, this machine, one process
    pools, how = _pools(args.data_dir)
    demos = 2 * sum(pools.values())  # the 4- and 10-choice suite of each family share the pool
    total_frames = demos * frames_per_demo
    print(f"\nper demo: {frames_per_demo:.0f} frames, expert {expert_per_demo:.2f} s; per frame here (render + "
          f"encode + write, one process): {1e3 * render_per_frame:.1f} ms, of which encoding alone "
          f"{1e3 * encode_per_frame:.1f} ms")
    print(f"paper training sets: pools {pools} ({how}) -> {demos} demos, ~{total_frames / 1e6:.2f} M frames")
    best = max(runs, key=lambda k: runs[k]["frames"] / runs[k]["wall"])
    here = total_frames / (runs[best]["frames"] / runs[best]["wall"])
    print(f"projected here at the best measured rate ({best}): {here / 3600:.1f} h")
    write("dataset_throughput", {
        "runs": {label: {k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()}
                 for label, r in runs.items()},
        "worker_scaling": round(fps[2] / fps[1], 2), "two_procs_over_default": round(fps[2] / fps[0], 2),
        "expert_s_per_demo": round(expert_per_demo, 3), "frame_ms": round(1e3 * render_per_frame, 1),
        "encode_ms": round(1e3 * encode_per_frame, 1), "paper_sets_projected_h_here": round(here / 3600, 1),
        "table": table(["build", "demos", "frames", "wall", "demos/min", "rendered frames/s", "CPU cores busy"],
                       [[label, r["episodes"], f"{r['frames']:,}", f"{r['wall']:.1f} s",
                         f"{60 * r['episodes'] / r['wall']:.1f}", f"{r['frames'] / r['wall']:.1f}",
                         f"{r['cores']:.2f}"] for label, r in runs.items()])})


if __name__ == "__main__":
    main()
