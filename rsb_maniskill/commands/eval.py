"""`rsb eval`: a policy on RSB suites with the paper's protocol; GSR / TSR / nSG tables.

    rsb eval oracle --suites RSB-Math-4 -n 100
    rsb eval my_policies:make_policy -a checkpoint=ckpt/last --num-procs 2 --videos 5
    rsb eval remote -a host=gpu-box -a port=8000 --name pi05 --instruction normal blank shuffled
    rsb eval oracle --suites RSB-Math-4 -n 50 --sweep camera lang_layout    # robustness axes, levels 0-3
    rsb eval oracle --suites RSB-Math-4 -n 50 --perturb camera=2 noise=1   # one perturbed run

Output directory (``--out``, default ``results/<name>``): ``episodes.jsonl`` (one record per
finished episode; rerunning the same command resumes), ``run.json`` (the settings each policy row
was run with; a resumed run must use the same ones, and the same benchmark version),
``summary.{json,csv,md}``, ``results.json`` (the shareable numbers, docs/evaluation.md), one
``summary_<row>.png`` per row, ``report.html`` (``rsb report``) and ``videos/``. See docs/evaluation.md.
"""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import unicodedata
from pathlib import Path
from typing import Any, Callable

from rsb_maniskill.commands.eval_args import (
    MANIFEST_KEYS,
    SEEDS_TEXT,
    EvalError,
    check_data,
    check_env_args,
    check_env_settings,
    check_policy_args,
    parse_kv,
    results_dir,
    run_settings,
)
from rsb_maniskill.debug import print_error
from rsb_maniskill.evaluation.store import ManifestError, RecordsError
from rsb_maniskill.policies.errors import POLICY_TIMEOUT_S, PolicyError

SWEEP_LEVELS = (0, 1, 2, 3)  # --sweep runs these, one after the other (level 0: the unperturbed run)


def register(subparsers: argparse._SubParsersAction) -> None:
    from rsb_maniskill.commands.eval_args import NameAction, ObsModeAction
    from rsb_maniskill.env_ids import CPU_SIM_BACKEND, GPU_SIM_BACKEND, TASK_MAX_EPISODE_STEPS, add_suites_argument
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE, EVAL_ENV_KWARGS
    from rsb_maniskill.evaluation.records import EVAL_INSTRUCTION_MODES
    from rsb_maniskill.parallel.plan import add_worker_args
    from rsb_maniskill.perturb import AXES
    from rsb_maniskill.policies.registry import POLICIES
    from rsb_maniskill.policies.remote.batching import DEFAULT_MAX_BATCH, DEFAULT_MAX_WAIT_MS
    from rsb_maniskill.robot import CONTROL_MODE

    state_only = [name for name, spec in POLICIES.items() if spec.obs_mode == "state"]

    p = subparsers.add_parser(
        "eval", help="evaluate a policy: GSR / TSR / nSG per suite (paper protocol)",
        description=f"Runs POLICY on the evaluation split ({EVAL_ENV_KWARGS['instructions']} instructions, fixed "
                    f"seeds {SEEDS_TEXT}) of each suite and writes per-episode records and GSR / TSR / nSG summaries. "
                    "Rerunning the same command resumes an interrupted run.")
    p.add_argument("policy", help=f"built-in ({', '.join(POLICIES)}) or package.module:factory")
    p.add_argument("-a", "--policy-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="keyword argument of the policy factory (VALUE parsed as JSON, else a string); repeatable")
    add_suites_argument(p)
    n_suites = len(p.get_default("suites"))
    total = EPISODES_PER_SUITE * n_suites
    p.description += (f" The defaults are the paper's protocol, a long run: {n_suites} suites x {EPISODES_PER_SUITE} "
                      f"episodes = {total:,} episodes, hours on a CPU machine; try --suites RSB-Math-4 -n 20 first.")
    p.add_argument("-n", "--num-episodes", type=int, default=EPISODES_PER_SUITE,
                   help=f"episodes per suite (default {EPISODES_PER_SUITE}: {total:,} episodes on the default "
                        "suites, hours on a CPU machine; each more --instruction mode or --sweep level runs them "
                        "again); the first n are a prefix of any longer run")
    p.add_argument("--instruction", nargs="+", default=["normal"], choices=EVAL_INSTRUCTION_MODES,
                   help="instruction given to the policy: normal, blank or shuffled (another episode's); "
                        "counterfactual: K variants of each scene, the answer on another candidate each "
                        "(follow / switch / stuck rates); several run one after the other")
    p.add_argument("--variants", type=int, default=None, metavar="K",
                   help="counterfactual variants per scene, 2..N (default: min(N, 4))")
    p.add_argument("--perturb", nargs="+", default=[], metavar="AXIS=LEVEL",
                   help="robustness axes applied together, each at a level 0-3 (axes: " + ", ".join(AXES) + "); "
                        "see docs/robustness.md")
    p.add_argument("--sweep", nargs="+", default=[], metavar="AXIS",
                   help="run each axis at levels 0-3, one after the other (level 0, the unperturbed run, once for "
                        "all); resumable; the summary and report.html get a robustness table per suite")
    p.add_argument("--name", default=None, action=NameAction,
                   help="row label in records and tables, on one line (default: the policy spec)")
    p.add_argument("--checkpoint", default=None, metavar="ID",
                   help="your id of the weights evaluated (a hub revision, a run name): results.json carries it")
    p.add_argument("--out", default=None, help="results directory (default: results/<name>)")
    p.add_argument("-o", "--obs-mode", default=None, action=ObsModeAction,
                   help=f"observations (default: rgb; state for {', '.join(state_only)})")
    p.add_argument("-c", "--control-mode", default=None, help=f"controller (default: the robot's {CONTROL_MODE})")
    p.add_argument("-e", "--env-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="extra gym.make keyword, e.g. camera_size=[224,224] (VALUE as JSON, else a string)")
    p.add_argument("--data-dir", default=None,
                   help="GSM8K / MMLU-Pro directory (else $RSB_DATA_DIR, else the hub cache)")
    p.add_argument("--num-envs", type=_num_envs, default=NUM_ENVS_NOT_GIVEN, metavar="auto|K",
                   help=f"envs a process, driven by one batched policy (reset_batch / act_batch; e.g. remote: "
                        "one request per step) or one policy instance each. On the CPU backend, a "
                        "vector of K CPU envs whose cameras render in one call where CUDA rendering exists "
                        "(the same episodes and records as K = 1); auto (default): 4 on NVIDIA GPUs when cameras "
                        f"render, else 1, printed with why. With -b {GPU_SIM_BACKEND}: ManiSkill's parallel envs on "
                        "GPU physics, in one process (default 1)")
    p.add_argument("-b", "--sim-backend", default=CPU_SIM_BACKEND, choices=(CPU_SIM_BACKEND, GPU_SIM_BACKEND),
                   help=f"physics: {CPU_SIM_BACKEND} (default; the paper's) or {GPU_SIM_BACKEND} (GPU-parallel envs, "
                        "with --num-envs K > 1)")
    p.add_argument("--max-steps", type=int, default=None,
                   help=f"step cap per episode (default: the task's {TASK_MAX_EPISODE_STEPS})")
    p.add_argument("--videos", type=int, default=0, metavar="K", help="mp4 of the first K episodes of each suite")
    p.add_argument("--policy-timeout", type=float, default=POLICY_TIMEOUT_S, metavar="SECONDS",
                   help=f"longest one policy call (factory, reset, act) may take before the run stops with a "
                        f"policy error (default {POLICY_TIMEOUT_S:g}; 0: no limit). The episodes run in a worker "
                        "process, which is killed when a call outlasts it")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bars and no lines saying what the run chose (workers, envs, policy "
                        "process): errors, warnings and notes on the results only")
    add_worker_args(p)  # --num-procs auto|N, --executor, --address
    p.add_argument("--policy-process", choices=("auto", "shared", "worker"), default="auto",
                   help="shared: the policy built once, in a server process of its own that answers every worker's "
                        "envs in one batched call (rsb serve over loopback); worker: one policy per worker; auto "
                        "(default): shared for a policy that declares a model computed on a GPU (heavy, gpu) with "
                        "several workers on a machine with CUDA, else worker; printed with why")
    p.add_argument("--max-batch", type=int, default=DEFAULT_MAX_BATCH, metavar="B",
                   help=f"shared policy: rows (envs) one policy call answers at most (default {DEFAULT_MAX_BATCH})")
    p.add_argument("--max-wait-ms", type=float, default=DEFAULT_MAX_WAIT_MS, metavar="T",
                   help="shared policy: how long a request waits for other workers' to join its batch, unless "
                        f"every worker's is in (default {DEFAULT_MAX_WAIT_MS:g})")
    p.set_defaults(func=run_eval)


def perturbations(perturb: list[str], sweep: list[str]) -> list[dict[str, int]]:
    """The perturbations to run, in order: ``--perturb`` (one, its axes together) or ``--sweep``
    (no perturbation, then each axis at levels 1-3); ``[{}]`` without either."""
    from rsb_maniskill.perturb import PerturbError, check_axis, parse_perturb

    if perturb and sweep:
        raise EvalError("use --perturb or --sweep, not both (a sweep varies one axis at a time)")
    try:
        if sweep:
            for axis in sweep:
                check_axis(axis)
            return [{}] + [{axis: level} for axis in dict.fromkeys(sweep) for level in SWEEP_LEVELS if level]
        return [parse_perturb(",".join(perturb))]
    except PerturbError as err:
        raise EvalError(f"{err} (--perturb AXIS=LEVEL, --sweep AXIS)") from None


def check_variants(variants: int | None, modes: list[str], suites: list[str]) -> None:
    """``--variants K``: only with ``--instruction counterfactual``, and 2 <= K <= N for every suite."""
    from rsb_maniskill.evaluation.protocol import COUNTERFACTUAL, scene_variants

    if variants is None:
        return
    if COUNTERFACTUAL not in modes:
        raise EvalError("--variants sets the counterfactual variants per scene: add --instruction counterfactual")
    for suite in suites:
        try:
            scene_variants(suite, variants)
        except ValueError as err:
            raise EvalError(f"--variants {variants} on {suite}: {err}") from None


def episodes_per_scene(suite: str, mode: str, variants: int | None) -> int:
    """Episodes a scene gives in ``mode``: K in counterfactual mode, else 1."""
    from rsb_maniskill.evaluation.protocol import COUNTERFACTUAL, scene_variants

    return scene_variants(suite, variants) if mode == COUNTERFACTUAL else 1


def check_policy_spec(spec: str, num_envs: int = 1) -> None:
    """Fail before any env is built when a spec cannot resolve, or cannot run on parallel envs."""
    from rsb_maniskill.policies.registry import policy_spec, resolve_factory

    if num_envs > 1 and policy_spec(spec).single_env:
        raise EvalError(f"policy {spec!r} drives one env at a time: with -b physx_cuda use --num-procs, not --num-envs")
    try:
        resolve_factory(spec)
    except ImportError as err:
        raise EvalError(f"{err}; is the module installed or on PYTHONPATH?") from err
    except (ValueError, AttributeError, TypeError) as err:
        raise EvalError(str(err)) from err


NUM_ENVS_NOT_GIVEN = object()  # --num-envs left out: auto on the CPU backend, 1 with GPU physics


def _num_envs(text: str) -> int | None:
    """A ``--num-envs`` value: ``auto`` (None: decided from the machine) or a count >= 1."""
    if text.strip().lower() == "auto":
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be auto or a whole number of envs >= 1, got {text!r}") from None


def check_batching(max_batch: int, max_wait_ms: float) -> None:
    """``--max-batch`` / ``--max-wait-ms``: values a shared policy server runs with, else a usage error."""
    from rsb_maniskill.policies.remote.batching import MAX_WAIT_LIMIT_MS

    if max_batch < 1:
        raise EvalError(f"--max-batch must be a whole number of rows >= 1, got {max_batch}")
    if not 0 <= max_wait_ms <= MAX_WAIT_LIMIT_MS:  # NaN and inf too
        raise EvalError(f"--max-wait-ms must be from 0 to {MAX_WAIT_LIMIT_MS:g} ms, got {max_wait_ms:g}")


def _info(quiet: bool) -> Callable[[str], None]:
    """Where a line saying what the run chose goes: stderr, or nowhere with -q (errors, warnings, notes)."""
    if quiet:
        return lambda line: None
    return lambda line: print(line, file=sys.stderr, flush=True)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def run_eval(args: argparse.Namespace) -> int:
    # SIGTERM (a scheduler's stop) ends the run like Ctrl-C: workers stopped, summary written.
    from rsb_maniskill.evaluation.jobs import PACE, JobError

    PACE.start()  # the start-up of the throughput line is timed from here
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        with _data_dir_for_the_run(args.data_dir):
            return _run_eval(args)
    except (EvalError, ManifestError, RecordsError) as err:
        print(f"rsb eval: error: {err}", file=sys.stderr)
        return 2
    except (PolicyError, JobError) as err:  # finished episodes are kept
        return print_error("eval", err, 1, hint=isinstance(err, PolicyError) or bool(err.detail),
                           then=getattr(err, "then", None) or "fix it and rerun the same command: finished "
                                                              "episodes are kept")
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run_jobs(args: argparse.Namespace, suites: list[str], label: str, policy_kwargs: dict, obs_mode: str,
              max_steps: int, env_kwargs: dict, out: Path, records_path: Path, num_procs: int,
              executor: Any, perturbs: list[dict[str, int]], stamp: dict[str, str], policy: str | None = None) -> None:
    """Every suite x instruction mode x perturbation, one after the other; ``stamp``: the settings id
    each record carries; ``policy``, ``policy_kwargs``: what the workers build (the shared server's client)."""
    from rsb_maniskill.evaluation.jobs import EvalJob, run_job
    from rsb_maniskill.evaluation.protocol import COUNTERFACTUAL, eval_seed_range

    for suite in suites:
        for mode, perturb in ((m, p) for m in args.instruction for p in perturbs):
            job = EvalJob(perturb=perturb or None,
                suite_id=suite, seeds=eval_seed_range(suite, args.num_episodes), policy=policy or args.policy,
                label=label, policy_kwargs=policy_kwargs, instruction_mode=mode, obs_mode=obs_mode,
                variants=args.variants if mode == COUNTERFACTUAL else None,
                control_mode=args.control_mode, num_envs=args.num_envs, sim_backend=args.sim_backend,
                max_steps=max_steps,
                env_kwargs=env_kwargs, video_dir=str(out / "videos") if args.videos else None,
                num_videos=args.videos, policy_timeout=args.policy_timeout or None)
            run_job(job, records_path, num_procs=num_procs, progress=not args.quiet, executor=executor, isolate=True,
                    stamp=stamp)


def _shared_server(args: argparse.Namespace, stack: contextlib.ExitStack, num_procs: int, policy_kwargs: dict,
                   info: Callable[[str], None]) -> Any:
    """``--policy-process``: the shared policy server (started on ``stack``, stopped with it), or None when
    each worker builds its own policy; the choice is printed with why."""
    from rsb_maniskill.policies.remote.shared import SharedServer, choose

    try:
        choice, why = choose(args.policy_process, args.policy, num_procs, local=args.executor == "local")
    except ValueError as err:
        raise EvalError(str(err)) from None
    if (args.policy_process == "auto" and num_procs > 1) or choice == "shared":
        where = "one server process for every worker" if choice == "shared" else "one per worker"
        info(f"rsb eval: policy process: {choice} ({where}): {why}")
    if choice != "shared":
        return None
    return stack.enter_context(SharedServer(args.policy, policy_kwargs, max_batch=args.max_batch,
                                            max_wait_ms=args.max_wait_ms, start_timeout=args.policy_timeout or None,
                                            policy_timeout=args.policy_timeout or None, quiet=args.quiet,
                                            workers=num_procs))


def _say_episodes(records: list[dict], out: Path) -> None:
    """The run's episodes not the version's (other question data): said at the end, as the summaries do."""
    from rsb_maniskill.evaluation.provenance import PINNED, check_records
    from rsb_maniskill.evaluation.store import read_manifest

    found = check_records(records, runs=read_manifest(out))
    if found.verdict != PINNED:
        print(f"rsb eval: warning: {found.text()}", file=sys.stderr)


@contextlib.contextmanager
def _data_dir_for_the_run(data_dir: str | None) -> Any:
    """``--data-dir`` as the run's question data in every process (this one, its workers: they inherit
    it), for whatever reads the data without being handed it: $RSB_DATA_DIR for the run, then restored."""
    import os

    if not data_dir:
        yield
        return
    old = os.environ.get("RSB_DATA_DIR")
    os.environ["RSB_DATA_DIR"] = str(Path(data_dir).expanduser().absolute())
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("RSB_DATA_DIR", None)
        else:
            os.environ["RSB_DATA_DIR"] = old


def _print_counterfactual(records: list[dict]) -> None:
    """The follow / switch / stuck tables of counterfactual runs (nothing without them)."""
    from rsb_maniskill.reporting.sections.counterfactual import counterfactual_markdown, counterfactual_table

    table = counterfactual_table(records)
    if table:
        print(counterfactual_markdown(table))


def _run_eval(args: argparse.Namespace) -> int:
    from rsb_maniskill.env_ids import GPU_SIM_BACKEND, TASK_MAX_EPISODE_STEPS
    from rsb_maniskill.evaluation.jobs import JobError
    from rsb_maniskill.evaluation.protocol import eval_seeds
    from rsb_maniskill.evaluation.provenance import check_question_pool
    from rsb_maniskill.evaluation.store import (
        RECORDS_FILE,
        SETTINGS_FIELD,
        RunStart,
        check_manifest,
        read_records,
        settings_id,
    )
    from rsb_maniskill.parallel.plan import executor_from_args, obs_mode_renders, resolve_num_envs, resolve_workers
    from rsb_maniskill.parallel.pool import ProcessPool
    from rsb_maniskill.parallel.ray_pool import RayExecutor
    from rsb_maniskill.policies.registry import factory_path, policy_spec
    from rsb_maniskill.version import BENCHMARK_VERSION

    suites = args.suites
    info = _info(args.quiet)  # lines that say what the run chose: not with -q
    gpu_physics = args.sim_backend == GPU_SIM_BACKEND
    if args.num_envs is NUM_ENVS_NOT_GIVEN:
        args.num_envs = 1 if gpu_physics else None
    for flag, value, low in (("--num-episodes", args.num_episodes, 1), ("--num-envs", args.num_envs, 1),
                             ("--videos", args.videos, 0)):
        if value is not None and value < low:
            raise EvalError(f"{flag} must be >= {low}, got {value}")
    if args.max_steps is not None and args.max_steps < 1:
        raise EvalError(f"--max-steps must be >= 1, got {args.max_steps}")
    if not args.policy_timeout >= 0:  # NaN too
        raise EvalError(f"--policy-timeout must be >= 0 seconds (0: no limit), got {args.policy_timeout}")
    check_batching(args.max_batch, args.max_wait_ms)
    if gpu_physics and args.num_envs is None:
        raise EvalError(f"--num-envs auto picks CPU envs a process; with -b {GPU_SIM_BACKEND} give --num-envs K")
    if gpu_physics and (args.num_envs or 1) > 1 and (args.num_procs or 1) > 1 and args.executor == "local":
        raise EvalError(f"use either --num-envs with -b {GPU_SIM_BACKEND} (one process) or --num-procs, not both")
    obs_mode = args.obs_mode or policy_spec(args.policy).obs_mode
    said: list[str] = []  # --num-envs auto's line: printed once every argument is checked (an error is one line)
    if args.num_envs is None:
        args.num_envs = resolve_num_envs(None, obs_mode_renders(obs_mode), log=said.append)
    try:
        executor = executor_from_args(args.executor, args.address,
                                      gpus_per_task=1 if args.num_envs > 1 and gpu_physics else 0)
    except (ValueError, ImportError) as err:
        raise EvalError(str(err)) from err
    if args.num_envs > 1 and gpu_physics and executor is None:
        import torch

        from rsb_maniskill.sim.physx_gpu import PhysXGpuLibraryMissing, check_for_sim_backend

        if not torch.cuda.is_available():
            raise EvalError(f"--num-envs > 1 runs the GPU backend ({GPU_SIM_BACKEND}), and no CUDA device is visible; "
                            "use --num-procs on a CPU machine")
        try:
            check_for_sim_backend(GPU_SIM_BACKEND, args.num_envs)  # before any episode, not in a worker
        except PhysXGpuLibraryMissing as err:
            raise EvalError(str(err)) from err
    policy_kwargs = parse_kv(args.policy_arg, "--policy-arg")
    env_kwargs = parse_kv(args.env_arg, "--env-arg")
    check_env_args(env_kwargs, "use --perturb AXIS=LEVEL or --sweep AXIS (records carry them)")
    perturbs = perturbations(args.perturb, args.sweep)
    check_variants(args.variants, args.instruction, suites)
    if args.data_dir:
        env_kwargs["data_dir"] = args.data_dir
    check_policy_spec(args.policy, args.num_envs if gpu_physics else 1)  # CPU vector envs: one instance each
    check_policy_args(args.policy, policy_kwargs)
    check_env_settings(suites, env_kwargs, obs_mode, args.control_mode)
    check_data(suites, env_kwargs.get("data_dir"), env_kwargs.get("color_map"))
    if args.policy == "remote":
        from rsb_maniskill.policies.remote import check_remote_args

        try:
            check_remote_args(policy_kwargs, args.obs_mode or "rgb")
        except (ValueError, ConnectionError) as err:
            raise EvalError(str(err)) from err

    # one spelling of a name: "é" typed as one code point or as e + accent names the same row and folder
    label = unicodedata.normalize("NFC", args.name or args.policy)
    out = results_dir(args.out, label)
    max_steps = args.max_steps or TASK_MAX_EPISODE_STEPS
    settings = run_settings(dict(  # (remote: without host, port, token: a resume on another port is the same run)
        policy=args.policy, policy_kwargs=policy_kwargs, obs_mode=obs_mode, control_mode=args.control_mode,
        max_steps=max_steps, env_kwargs=env_kwargs, benchmark_version=BENCHMARK_VERSION, checkpoint=args.checkpoint,
        policy_factory=factory_path(args.policy)))  # a resume checks its records came from this code
    pool = check_question_pool(read_records(out / RECORDS_FILE), label, env_kwargs.get("data_dir"),
                               env_kwargs.get("color_map", "fixed"))
    if pool:  # a resume on other question data would pool two question pools in one summary
        raise EvalError(pool)
    start = RunStart(out)  # taken back if the run fails before its first episode
    note = check_manifest(out, label, settings, keys=MANIFEST_KEYS, read_row=run_settings)
    if note:
        print(f"rsb eval: note: {note}", file=sys.stderr)

    records_path = out / RECORDS_FILE
    interrupted = False
    with contextlib.ExitStack() as stack:
        if executor is not None:
            stack.enter_context(executor)  # a local Ray cluster lives for the whole run
        for line in said:
            info(line)
        episodes = args.num_episodes * max(episodes_per_scene(s, m, args.variants)
                                           for s in suites for m in args.instruction)  # a job's, at most
        executor, num_procs = resolve_workers(args.num_procs, executor, obs_mode_renders(obs_mode) or args.videos > 0,
                                              num_envs=args.num_envs, episodes=episodes, gpu_physics=gpu_physics,
                                              log=info)
        a_worker = -(-episodes // num_procs)
        if args.num_envs > a_worker:  # K envs for fewer episodes would build envs for nothing
            info(f"envs: {a_worker} a process (--num-envs {args.num_envs}: no more than the {a_worker} episodes a "
                 "worker runs)")
            args.num_envs = a_worker
        server = None
        try:
            server = _shared_server(args, stack, num_procs, policy_kwargs, info)  # --policy-process
            if not isinstance(executor, RayExecutor):  # workers started once for every suite, mode, perturbation
                executor = stack.enter_context(executor or ProcessPool())
            _run_jobs(args, suites, label, server.client_kwargs() if server else policy_kwargs, obs_mode, max_steps,
                      env_kwargs, out, records_path, num_procs, executor, perturbs,
                      {SETTINGS_FIELD: settings_id(settings, MANIFEST_KEYS)}, policy="remote" if server else None)
        except KeyboardInterrupt:
            interrupted = True
        except (PolicyError, JobError, EvalError) as err:  # EvalError: --policy-process refused
            start.undo(label)
            if server is not None:
                server.check()  # a dead server is the cause: said in one line
            raise err

    from rsb_maniskill.evaluation.records import perturb_label as record_perturb
    from rsb_maniskill.perturb import label as perturb_label
    from rsb_maniskill.reporting.sections.reasoning import reasoning_markdown, reasoning_table
    from rsb_maniskill.reporting.sections.robustness import robustness_markdown, robustness_table
    from rsb_maniskill.reporting.summary import markdown_tables, results_from_records
    from rsb_maniskill.reporting.writer import write_html_report, write_report

    wanted = {(s, m, perturb_label(p)) for s in suites for m in args.instruction for p in perturbs}
    all_records = read_records(records_path)
    results = results_from_records(all_records)
    asked = [r for r in all_records if r["policy"] == label
             and (r["suite_id"], r["instruction_mode"], record_perturb(r)) in wanted]
    n_run = sum(1 for r in asked if int(r["seed"]) - eval_seeds(r["suite_id"], 1)[0] < args.num_episodes
                and int(r.get("variant", 0)) < episodes_per_scene(r["suite_id"], r["instruction_mode"], args.variants))
    expected = sum(args.num_episodes * episodes_per_scene(s, m, args.variants) for s, m, _ in wanted)
    partial = f"partial: interrupted, {n_run} of {expected} episodes" if interrupted else None
    if results:
        paths = write_report(results, out, records=all_records, partial=partial)
        page = write_html_report(out, records=all_records, partial=partial)
        print(markdown_tables(results, BENCHMARK_VERSION))
        robust = robustness_table(all_records)
        if robust:
            print(robustness_markdown(robust))
        _print_counterfactual(all_records)
        print(reasoning_markdown(reasoning_table(all_records)), end="")  # nothing unless a policy talked
        print(f"records: {records_path}\nsummary: {paths['markdown']}, {paths['json']}, {paths['csv']}\n"
              f"results: {paths['results']}\nreport: {page}")
        _say_episodes(asked, out)
        from rsb_maniskill.evaluation.jobs import PACE

        print(PACE.line())  # start-up seconds, then steady env-steps/s
    if interrupted:
        print(f"rsb eval: interrupted; finished episodes are in {records_path}. "
              "Rerun the same command to resume.", file=sys.stderr)
        return 130
    if len(asked) > n_run:  # the summary is of the whole folder: say what it holds beyond this run
        print(f"rsb eval: note: the summary covers every record in {out}: {len(asked)} episodes of {label!r} on "
              f"these suites, {len(asked) - n_run} more than this run's -n {args.num_episodes} (from an earlier, "
              "longer run)", file=sys.stderr)
    if n_run != expected:
        print(f"rsb eval: warning: {n_run} of {expected} episodes recorded", file=sys.stderr)
        return 1
    return 0
