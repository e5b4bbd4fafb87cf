"""Evaluation harness of RSB: GSR / TSR / nSG of any policy on the fixed protocol.

Simulator-independent: these modules see the env only through the task contract (see
``runner.py``), so they import fast and are tested without physics. See docs/evaluation.md.

Layers, each importing only those below it: the commands (``cli/``: ``rsb eval``, ``rsb backbone``,
``rsb report``) over the reports (``reporting/``: summaries, results.json, report.html) and the
remote policies (``remote/``), over this library (the loops, the driver, policies, backbones, the
protocol, metrics), over what a record is (``records.py``) and where records live (``store.py``).
The reports are not re-exported here: import them from ``reporting/``.
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
from rsb_maniskill.evaluation.policy import (
    BatchedPolicy,
    PerEnvPolicies,
    Policy,
    RandomPolicy,
    as_chunk,
    builtin_policies,
    load_policy,
    policy_name,
    register_policy,
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
    "EvalJob", "INSTRUCTION_MODES", "BatchedPolicy", "PerEnvPolicies", "PAPER_SUITES", "Policy", "RECORD_FIELDS",
    "RandomPolicy", "Rate",
    "RecordWriter", "SuiteMetrics", "apply_instruction_mode", "as_chunk", "average", "batched_loop", "build_record",
    "builtin_policies", "completed_seeds", "derangement", "drive", "episode_loop", "eval_seeds", "load_policy",
    "nsg", "num_choices", "policy_name", "read_records", "register_policy",
    "run_episodes", "run_job", "shuffled_instruction", "summarize", "suite_metrics",
    "wilson_interval",
    "Backbone", "MAX_TEXT_CHARS", "ask_episodes", "load_backbone", "reasoning_following",
]
