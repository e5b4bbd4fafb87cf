"""`rsb backbone`: ask a policy's backbone the protocol's questions, exactly as the policy gets them.

    rsb backbone arithmetic --suites RSB-Math-4 RSB-Math-10 --out results/blind
    rsb backbone my_models:make_backbone -a path=ckpt --suites paper --images --out results/pi05
    rsb backbone remote -a host=gpu-box -a port=8001 --name qwen3-4b --out results/pi05

The backbones and the asking are ``evaluation/backbone.py``; the answers go to ``<out>/backbone.jsonl``
beside an eval run's ``episodes.jsonl`` (rerunning resumes), and with both the summaries and
report.html show the semantic gap (``reporting/sections/gap.py``).
"""
from __future__ import annotations

import argparse
import os
import sys

from rsb_maniskill.commands.eval_args import (
    BACKBONE_KEYS,
    EVAL_FLAG_KEYS,
    EvalError,
    check_data,
    check_env_args,
    check_env_settings,
    parse_kv,
    results_dir,
    run_settings,
)
from rsb_maniskill.evaluation.store import ManifestError, RecordsError

# gym.make keywords rsb backbone sets itself (it builds its env only to render first frames)
OWN_ENV_KEYS = {key: "rsb backbone builds its env with its own" for key in EVAL_FLAG_KEYS}


def register(subparsers: argparse._SubParsersAction) -> None:
    from rsb_maniskill.commands.eval_args import NameAction
    from rsb_maniskill.env_ids import add_suites_argument
    from rsb_maniskill.evaluation.backbone import BACKBONES
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE
    from rsb_maniskill.evaluation.records import INSTRUCTION_MODES
    from rsb_maniskill.evaluation.store import BACKBONE_FILE, RECORDS_FILE

    p = subparsers.add_parser(
        "backbone", help="ask a backbone the protocol's questions as the policy gets them (the semantic gap)",
        description="Asks MODEL the evaluation episodes of each suite (instruction after the same ablation as "
                    "`rsb eval --instruction`; with --images also the head camera's first frame), parses its "
                    f"answers like a talking policy's text and writes OUT/{BACKBONE_FILE} beside an eval run's "
                    f"{RECORDS_FILE}. With both, the summaries and report.html show the semantic gap.")
    p.add_argument("backbone", metavar="MODEL", help=f"built-in ({', '.join(BACKBONES)}) or package.module:factory")
    p.add_argument("-a", "--backbone-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="keyword argument of the backbone factory (VALUE parsed as JSON, else a string); repeatable")
    add_suites_argument(p)
    n_suites = len(p.get_default("suites"))
    p.add_argument("-n", "--num-episodes", type=int, default=EPISODES_PER_SUITE,
                   help=f"episodes per suite (default {EPISODES_PER_SUITE}: {EPISODES_PER_SUITE * n_suites:,} "
                        "questions to MODEL on the default suites); the same seeds as rsb eval -n")
    p.add_argument("--instruction", nargs="+", default=["normal"], choices=INSTRUCTION_MODES,
                   help="instruction given: normal, blank or shuffled (as rsb eval --instruction)")
    p.add_argument("--images", action="store_true",
                   help="also send the head camera's first frame (renders each episode's first observation)")
    p.add_argument("--name", default=None, action=NameAction,
                   help="row label in records and tables, on one line (default: the backbone spec)")
    p.add_argument("--out", default=None, help="results directory, e.g. the --out of an rsb eval run "
                                               "(default: results/<name>)")
    p.add_argument("-e", "--env-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="gym.make keyword of the eval run, e.g. camera_size=[224,224] (for --images)")
    p.add_argument("--data-dir", default=None, help="GSM8K / MMLU-Pro directory (else $RSB_DATA_DIR)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run_backbone)


def run_backbone(args: argparse.Namespace) -> int:
    try:
        return _run_backbone(args)
    except (EvalError, ManifestError, RecordsError) as err:
        print(f"rsb backbone: error: {err}", file=sys.stderr)
        return 2


def _run_backbone(args: argparse.Namespace) -> int:
    from rsb_maniskill.evaluation.backbone import ask_episodes, load_backbone, resolve_backbone
    from rsb_maniskill.evaluation.protocol import eval_seeds
    from rsb_maniskill.evaluation.store import (
        BACKBONE_FILE,
        RECORDS_FILE,
        check_manifest,
        read_backbone_records,
        read_records,
    )
    from rsb_maniskill.reporting.sections.gap import backbone_markdown, gap_markdown, gap_table

    suites = args.suites  # resolved at parse time (env_ids.add_suites_argument)
    if args.num_episodes < 1:
        raise EvalError(f"--num-episodes must be >= 1, got {args.num_episodes}")
    kwargs = parse_kv(args.backbone_arg, "--backbone-arg")
    env_kwargs = parse_kv(args.env_arg, "--env-arg")
    check_env_args(env_kwargs, "rsb backbone asks the questions of the unperturbed episodes", OWN_ENV_KEYS)
    check_env_settings(suites, env_kwargs)
    if args.data_dir:
        env_kwargs["data_dir"] = args.data_dir
    try:
        resolve_backbone(args.backbone)
    except ImportError as err:
        raise EvalError(f"{err}; is the module installed or on PYTHONPATH?") from err
    except (ValueError, AttributeError, TypeError) as err:
        raise EvalError(str(err)) from err
    check_data(suites, env_kwargs.get("data_dir"))
    label = args.name or args.backbone
    out = results_dir(args.out, label)
    note = check_manifest(out, label, run_settings(dict(backbone=args.backbone, backbone_kwargs=kwargs,
                                                        images=args.images, env_kwargs=env_kwargs)),
                          section="backbones", keys=BACKBONE_KEYS, read_row=run_settings)
    if note:
        print(f"rsb backbone: note: {note}", file=sys.stderr)
    if args.quiet:
        _quiet_libraries()
    try:
        backbone = load_backbone(args.backbone, **kwargs)
    except (TypeError, ValueError, ImportError, ConnectionError) as err:
        raise EvalError(f"cannot build backbone {args.backbone!r}: {err}") from err
    path = out / BACKBONE_FILE
    try:
        for suite in suites:
            for mode in args.instruction:
                ask_episodes(backbone, suite, eval_seeds(suite, args.num_episodes), path, label=label,
                             instruction_mode=mode, images=args.images, env_kwargs=env_kwargs, progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"rsb backbone: interrupted; answered questions are in {path}. Rerun to resume.", file=sys.stderr)
        return 130
    finally:
        close = getattr(backbone, "close", None)
        if callable(close):
            close()
    answers = read_backbone_records(path)
    print(backbone_markdown(answers))
    episodes = read_records(out / RECORDS_FILE) if (out / RECORDS_FILE).exists() else []
    if episodes:
        from rsb_maniskill.reporting.summary import results_from_records
        from rsb_maniskill.reporting.writer import write_html_report, write_report

        paths = write_report(results_from_records(episodes), out, records=episodes)
        print(gap_markdown(gap_table(episodes, answers)))
        print(f"answers: {path}\nsummary: {paths['markdown']}\nreport: {write_html_report(out, records=episodes)}")
    else:
        print(f"answers: {path}\n(no {RECORDS_FILE} in {out}: run `rsb eval ... --out {out}` to see the gap)")
    return 0


def _quiet_libraries() -> None:
    """``-q``: the progress bars of what a backbone loads (a model's "Loading weights") stay off too."""
    os.environ["HF_HUB_DISABLE_PROGRESS_BARS"] = "1"  # a library imported from here on reads it
    try:
        from huggingface_hub.utils import disable_progress_bars
    except ImportError:
        return
    disable_progress_bars()  # transformers asks huggingface_hub whether to draw its bars
    if "transformers" in sys.modules:
        sys.modules["transformers"].utils.logging.disable_progress_bar()
