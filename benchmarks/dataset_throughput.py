"""Throughput of `rsb dataset build`, and the projected time of the paper's six training sets.

One run builds the same questions of RSB-Math-4 with 1 and with 2 worker processes (three cameras at
320x240 unless --camera-size says otherwise) and prints demos/min and rendered frames/s of each, and
their ratio; it times the expert alone on the same questions to split a demo's cost into the
expert's share and the rendering + writing share; then it projects the wall time of the six paper
training sets (every training question of each suite, pools as the code has them) on this machine
and on a 16-core machine with an NVIDIA GPU, whose three-camera render step was measured at
5.9 ms (docs/gpu.md). Run it on an otherwise idle machine:

    python benchmarks/dataset_throughput.py --questions 8
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

GPU_STEP_S = 5.9e-3  # three 320x240 cameras, physx_cpu, one process, NVIDIA H100 (docs/gpu.md)
GPU_BOX_CORES = 16
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


def _expert_only(out: Path, n: int) -> float:
    from rsb_maniskill.motionplan.generate import GenerateConfig, generate
    from rsb_maniskill.workers import InProcess

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
    args = ap.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")  # pool sizes: local data or the fallback, no network waits
    size = tuple(int(v) for v in args.camera_size.split("x"))
    load_before = os.getloadavg()[0]  # read before the runs: other work on the machine skews every figure
    tmp = Path(tempfile.mkdtemp(prefix="rsb-dataset-bench-"))
    try:
        runs = {}
        for procs in (1, 2):
            wall, s, cores = _build(tmp / f"p{procs}", procs, args.questions, size)
            runs[procs] = (wall, s["episodes"], s["frames"], cores)
        expert_s = _expert_only(tmp / "expert", args.questions)
        encode_per_frame = _encode_per_frame(size, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"machine: {os.cpu_count()} CPUs, load before: {load_before:.2f}; cameras 3 x {size[0]}x{size[1]}")
    for procs, (wall, eps, frames, cores) in runs.items():
        print(f"{procs} process(es): {eps} demos, {frames} frames in {wall:.1f} s -> {60 * eps / wall:.1f} demos/min, "
              f"{frames / wall:.1f} rendered frames/s, {cores:.2f} CPU cores busy on average")
    ratio = (runs[2][2] / runs[2][0]) / (runs[1][2] / runs[1][0])
    print(f"frames/s with 2 processes / with 1: {ratio:.2f}x (target >= 1.8x)")

    wall1, eps, frames, _ = runs[1]
    frames_per_demo = frames / eps
    expert_per_demo = expert_s / eps
    render_per_frame = max(wall1 - expert_s, 0.0) / frames  # render + encode + write, this machine, one process
    pools, how = _pools(args.data_dir)
    demos = 2 * sum(pools.values())  # the 4- and 10-choice suite of each family share the pool
    total_frames = demos * frames_per_demo
    print(f"\nper demo: {frames_per_demo:.0f} frames, expert {expert_per_demo:.2f} s; per frame here (render + encode + "
          f"write, one process): {1e3 * render_per_frame:.1f} ms, of which encoding alone {1e3 * encode_per_frame:.1f} ms")
    print(f"paper training sets: pools {pools} ({how}) -> {demos} demos, ~{total_frames / 1e6:.2f} M frames")
    here = (demos * expert_per_demo + total_frames * render_per_frame) / max(1, os.cpu_count() or 1)
    print(f"projected here ({os.cpu_count()} processes): {here / 3600:.1f} h")
    # GPU box: the expert and the encoding scale with cores (counted in full, not overlapped); a
    # render step costs GPU_STEP_S per process (measured with one process).
    gpu = (demos * expert_per_demo + total_frames * (GPU_STEP_S + encode_per_frame)) / GPU_BOX_CORES
    serial = total_frames * GPU_STEP_S  # worst case: the GPU renders one process at a time
    print(f"projected on a {GPU_BOX_CORES}-core NVIDIA GPU machine: {gpu / 3600:.2f} h (render steps of "
          f"{1e3 * GPU_STEP_S:.1f} ms spread over {GPU_BOX_CORES} processes; target <= 2 h); if the GPU served "
          f"one process at a time: {serial / 3600:.1f} h")


if __name__ == "__main__":
    main()
