"""Evaluation harness of RSB: GSR / TSR / nSG of any policy on the fixed protocol.

Simulator-independent: these modules see the env only through the task contract (see
``runner.py``), so they import fast and are tested without physics. See docs/evaluation.md.

The library of the harness: the loops and the driver (``runner.py``, ``jobs.py``), backbones, the
protocol, metrics, what a record is (``records.py``) and where records live (``store.py``). Policies
are ``rsb_maniskill.policies``, the reports ``rsb_maniskill.reporting``, the commands
``rsb_maniskill.commands``.
"""
from __future__ import annotations

from rsb_maniskill.evaluation.backbone import Backbone, ask_episodes, load_backbone
from rsb_maniskill.evaluation.jobs import EvalJob, drive, run_episodes, run_job
from rsb_maniskill.evaluation.metrics import (
    PAPER_SUITES,
    Average,
    ErrorAnalysis,
    Rate,
    SuiteMetrics,
    average,
    nsg,
    num_choices,
    suite_metrics,
    summarize,
    wilson_interval,
)
from rsb_maniskill.evaluation.protocol import (
    EPISODES_PER_SUITE,
    EVAL_ENV_KWARGS,
    EVAL_SEED_BASE,
    apply_instruction_mode,
    derangement,
    eval_seeds,
    shuffled_instruction,
)
from rsb_maniskill.evaluation.records import INSTRUCTION_MODES, RECORD_FIELDS, build_record
from rsb_maniskill.evaluation.runner import EpisodeSettings, batched_loop, episode_loop
from rsb_maniskill.evaluation.statements import MAX_TEXT_CHARS, reasoning_following
from rsb_maniskill.evaluation.store import RecordWriter, completed_seeds, read_records

__all__ = [
    "Average", "EPISODES_PER_SUITE", "EVAL_ENV_KWARGS", "EVAL_SEED_BASE", "EpisodeSettings", "ErrorAnalysis",
    "EvalJob", "INSTRUCTION_MODES", "PAPER_SUITES", "RECORD_FIELDS", "Rate",
    "RecordWriter", "SuiteMetrics", "apply_instruction_mode", "average", "batched_loop", "build_record",
    "completed_seeds", "derangement", "drive", "episode_loop", "eval_seeds",
    "nsg", "num_choices", "read_records",
    "run_episodes", "run_job", "shuffled_instruction", "summarize", "suite_metrics",
    "wilson_interval",
    "Backbone", "MAX_TEXT_CHARS", "ask_episodes", "load_backbone", "reasoning_following",
]
