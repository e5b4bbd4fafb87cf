"""``rsb report`` on vla-eval results: a ``vla-eval run`` of RSBBenchmark read as RSB episode records.

vla-eval writes ``<output_dir>/<benchmark>_aggregate.json`` (``vla_eval/results/export.py``): the
benchmark's tasks, each with its episodes, each with the ``metrics`` RSBBenchmark returned, which
are the episode's ``rsb eval`` record plus ``gsr`` / ``tsr``. From those records come the paper's
tables with Wilson intervals and nSG (vla-eval reports ``mean_<key>`` only), ``summary.*`` and
``report.html``, as for an ``rsb eval`` run (``rsb report``, ``commands/report.py``, writes them).

An episode vla-eval ended with an error (``failure_reason``: server unreachable, timeout, ...) has
no RSB record; vla-eval counts it as a failure, and so does the reader (no grasp, no success),
with a warning saying how many.
"""
from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any, Mapping

from rsb_maniskill.evaluation.records import VERSION_FIELD, VLA_EVAL_RUNNER
from rsb_maniskill.evaluation.store import RECORDS_FILE

AGGREGATE_GLOB = "*_aggregate.json"  # vla-eval's results files


class NotRSBResults(ValueError):
    """A vla-eval results file of another benchmark."""


def results_files(path: str | os.PathLike) -> list[Path]:
    """The vla-eval results files ``path`` names: itself (a ``.json`` file) or those of a directory."""
    path = Path(path)
    if path.is_file():
        return [path] if path.suffix == ".json" else []
    return sorted(path.glob(AGGREGATE_GLOB)) if path.is_dir() else []


def is_vla_eval_results(path: str | os.PathLike) -> bool:
    """Whether ``rsb report PATH`` means vla-eval results: a results file, or a directory of them that
    holds no ``rsb eval`` records."""
    path = Path(path)
    return bool(results_files(path)) and not (path / RECORDS_FILE).exists()


def _failed_record(episode: Mapping[str, Any], task: str, params: Mapping[str, Any]) -> dict[str, Any]:
    from rsb_maniskill.evaluation.protocol import eval_seeds

    suite, i = str(episode.get("suite") or task), int(episode.get("episode_idx", episode.get("episode_id", 0)))
    return {"suite_id": suite, "seed": eval_seeds(suite, i + 1)[i],
            "policy": params.get("policy_name", VLA_EVAL_RUNNER),
            "instruction_mode": params.get("instruction_mode", "normal"), "grasped_any": False, "success": False,
            "steps": episode.get("steps", 0), "runner": VLA_EVAL_RUNNER,
            "failure_reason": episode.get("failure_reason")}


def records_from_results(results: Mapping[str, Any], source: str = "results") -> list[dict[str, Any]]:
    """The RSB records of one vla-eval results dict (errored episodes as failures, see the module doc)."""
    params = (results.get("config") or {}).get("params") or {}
    records, failed = [], 0
    for task in results.get("tasks") or []:
        for episode in task.get("episodes") or []:
            metrics = episode.get("metrics") or {}
            if "suite_id" in metrics:
                records.append({k: v for k, v in metrics.items() if k not in ("gsr", "tsr")})
            elif episode.get("failure_reason"):
                records.append(_failed_record(episode, task.get("task", ""), params))
                failed += 1
            else:
                raise NotRSBResults(f"{source}: episode {episode.get('episode_id')} of task {task.get('task')!r} has "
                                    f"no RSB record in its metrics ({sorted(metrics)}): not a vla-eval run of "
                                    "rsb_maniskill.integrations.vla_eval:RSBBenchmark")
    if failed:
        # An errored episode has no RSB record, so no benchmark version: it was run on the version of
        # the run's other episodes (when they agree), and must not read as unversioned beside them.
        versions = {r[VERSION_FIELD] for r in records if r.get(VERSION_FIELD)}
        if len(versions) == 1:
            for r in records:
                r.setdefault(VERSION_FIELD, next(iter(versions)))
        warnings.warn(f"{source}: {failed} episode(s) ended with an error in vla-eval (failure_reason); "
                      "counted as failures with no grasp, as vla-eval counts them", stacklevel=2)
    return records


def read_vla_eval_records(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The RSB records of every results file ``path`` names."""
    files = results_files(path)
    if not files:
        raise FileNotFoundError(f"{path}: no vla-eval results ({AGGREGATE_GLOB}) there")
    out = []
    for f in files:
        try:
            doc = json.loads(f.read_text(encoding="utf-8"))
        except ValueError as err:  # an empty or cut file: named, with where it breaks
            raise ValueError(f"{f}: not a vla-eval results file (JSON: {err})") from None
        if not isinstance(doc, dict):
            raise ValueError(f"{f}: not a vla-eval results file (a JSON object is due, not a {type(doc).__name__})")
        out += records_from_results(doc, str(f))
    return out
