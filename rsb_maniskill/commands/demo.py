"""`rsb demo`: the README's first command, the whole pipeline on an embedded default.

On RSB-Math-4 (procedural questions: no dataset needed) it writes, under ``--out``:

- ``cameras/``: what the head and wrist cameras and an outside camera see at the first step;
- ``demos/``: scripted-expert demonstrations in ManiSkill's trajectory format, one with a video;
- ``eval/``: the oracle and the blind baseline on the first evaluation episodes, with the
  GSR / TSR / nSG summary (Markdown, JSON, CSV, PNG), ``results.json``, a video of the first
  episode and ``report.html``, the page to open first (the last line printed names it).

About 35 s on two shared CPU cores (measured: 34 s and 38 s), after the set-up.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

DEFAULT_OUT = "outputs/demo"
DEFAULT_SUITE = "RSB-Math-4"


def register(subparsers) -> None:
    from rsb_maniskill.commands.vocab import add_old_spelling
    from rsb_maniskill.env_ids import add_suites_argument

    p = subparsers.add_parser(
        "demo", help="the pipeline on RSB-Math-4: camera pictures, expert demos, evaluation",
        description=f"The whole pipeline on one suite (default {DEFAULT_SUITE}: procedural questions, no data "
                    "needed), written under --out: what the cameras see at the first step, scripted-expert "
                    "demonstrations, and the oracle and blind baselines on the first -n evaluation episodes with "
                    "their summary and report.html (the last line printed names it).")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    add_suites_argument(p, default=(DEFAULT_SUITE,), positional=True,
                        help="the suite to run: one suite id or the paper release's task name (the demo runs one "
                             "suite; more are refused)")
    add_old_spelling(p, "--suite", "--suites")
    p.add_argument("--demos", type=int, default=3, help="expert demonstrations to generate (default 3)")
    p.add_argument("-n", "--num-episodes", dest="episodes", metavar="N", type=int, default=20,
                   help="episodes per suite: evaluation episodes of each baseline (default 20)")
    add_old_spelling(p, "--episodes", "--num-episodes")
    p.add_argument("--seed", type=int, default=0, help="episode seed of the camera pictures")
    p.set_defaults(func=run)


def save_camera_pictures(env, obs: dict, out: Path, prefix: str = "") -> list[Path]:
    """Writes each camera's RGB frame of env 0, and the outside view, as PNGs."""
    import cv2

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in obs["sensor_data"].items():
        path = out / f"{prefix}{name}.png"
        cv2.imwrite(str(path), data["rgb"][0].cpu().numpy()[..., ::-1])
        paths.append(path)
    path = out / f"{prefix}outside_view.png"
    cv2.imwrite(str(path), env.render()[0].cpu().numpy()[..., ::-1])
    paths.append(path)
    return paths


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401  (registers the envs)
    from rsb_maniskill.evaluation.jobs import EvalJob, run_job
    from rsb_maniskill.evaluation.protocol import eval_seeds
    from rsb_maniskill.evaluation.store import RECORDS_FILE, read_records
    from rsb_maniskill.motionplan.generate import GenerateConfig, describe, generate
    from rsb_maniskill.outdirs import writable_dir
    from rsb_maniskill.reporting.summary import markdown_tables, results_from_records
    from rsb_maniskill.reporting.writer import write_html_report, write_report
    from rsb_maniskill.sim.render import ensure_renderer
    from rsb_maniskill.version import BENCHMARK_VERSION

    for flag, value in (("-n/--num-episodes", args.episodes), ("--demos", args.demos)):
        if value < 1:
            print(f"rsb demo: error: {flag} must be >= 1 (a whole number to make), got {value}", file=sys.stderr)
            return 2
    if len(args.suites) != 1:
        print(f"rsb demo: error: give one suite, got {len(args.suites)}: {' '.join(args.suites)}", file=sys.stderr)
        return 2
    (args.suite,) = args.suites
    out = Path(args.out)
    try:  # every folder it writes, checked now, not after a minute of work
        for sub in ("cameras", "demos", "eval"):
            writable_dir(out / sub)
    except OSError as err:
        print(f"rsb demo: error: cannot write to {err.filename or out}: {err.strerror or err}; choose a writable "
              "--out or fix its permissions", file=sys.stderr)
        return 2
    ensure_renderer()

    print(f"[1/3] cameras: {args.suite}, seed {args.seed}")
    env = gym.make(args.suite, obs_mode="rgb", render_mode="rgb_array")
    obs, _ = env.reset(seed=args.seed)
    print(f"      instruction: {env.unwrapped.get_language_instruction()[0]}")
    hold = env.unwrapped.agent.rest_action()[None]
    for _ in range(5):  # let the rest pose settle before taking pictures
        obs, *_ = env.step(hold)
    for path in save_camera_pictures(env.unwrapped, obs, out / "cameras"):
        print(f"      wrote {path}")
    env.close()

    print(f"[2/3] {args.demos} expert demonstrations (train split)")
    summary = generate(GenerateConfig(env_id=args.suite, out=str(out / "demos"), num=args.demos,
                                      save_video=True, overwrite=True, progress=False))
    print("      " + describe(summary).replace("\n", "\n      "))

    print(f"[3/3] oracle and blind baselines, first {args.episodes} evaluation episodes")
    records = out / "eval" / RECORDS_FILE
    records.unlink(missing_ok=True)  # a fresh table each time
    for policy in ("oracle", "blind"):
        job = EvalJob(suite_id=args.suite, seeds=tuple(eval_seeds(args.suite, args.episodes)), policy=policy,
                      label=policy, obs_mode="state", video_dir=str(out / "eval" / "videos"), num_videos=1)
        run_job(job, records, progress=True)
    recs = read_records(records)
    results = results_from_records(recs)
    paths = write_report(results, out / "eval", records=recs)
    page = write_html_report(out / "eval", records=recs)
    print(markdown_tables(results, BENCHMARK_VERSION))
    print(f"wrote {', '.join(str(p) for p in paths.values())}")
    print(f"report: {page} (open it in a browser: tables, bars and every episode; each baseline's first "
          "one with its video)")
    return 0 if summary.completed == args.demos else 1
