"""Evaluation harness of RSB: GSR / TSR / nSG of any policy on the fixed protocol.

Simulator-independent: these modules see the env only through the task contract (see
``runner.py``), so they import fast and are tested without physics. See docs/evaluation.md.
"""
from __future__ import annotations

from .backbone import Backbone, ask_episodes, load_backbone
from .jobs import EvalJob, drive, run_episodes, run_job
from .metrics import (
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
from .policy import (
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
from .protocol import (
    EPISODES_PER_SUITE,
    EVAL_ENV_KWARGS,
    EVAL_SEED_BASE,
    apply_instruction_mode,
    derangement,
    eval_seeds,
    shuffled_instruction,
)
from .records import INSTRUCTION_MODES, RECORD_FIELDS, RecordWriter, completed_seeds, read_records
from .reporting.summary import markdown_tables, plot_summary, results_from_records, summary_dict, write_report
from .runner import EpisodeSettings, batched_loop, build_record, episode_loop
from .statements import MAX_TEXT_CHARS, reasoning_following

__all__ = [
    "Average", "EPISODES_PER_SUITE", "EVAL_ENV_KWARGS", "EVAL_SEED_BASE", "EpisodeSettings", "ErrorAnalysis",
    "EvalJob", "INSTRUCTION_MODES", "BatchedPolicy", "PerEnvPolicies", "PAPER_SUITES", "Policy", "RECORD_FIELDS",
    "RandomPolicy", "Rate",
    "RecordWriter", "SuiteMetrics", "apply_instruction_mode", "as_chunk", "average", "batched_loop", "build_record",
    "builtin_policies", "completed_seeds", "derangement", "drive", "episode_loop", "eval_seeds", "load_policy",
    "markdown_tables", "nsg", "num_choices", "plot_summary", "policy_name", "read_records", "register_policy",
    "results_from_records", "run_episodes", "run_job", "shuffled_instruction", "summarize", "suite_metrics",
    "summary_dict", "wilson_interval", "write_report",
    "Backbone", "MAX_TEXT_CHARS", "ask_episodes", "load_backbone", "reasoning_following",
]
