"""What a generation run did: the ``rsb`` block of the dataset json, its merge over shards, and the
summary ``rsb generate`` prints."""
from __future__ import annotations

import signal
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from rsb_maniskill.motionplan.config import GenerateConfig
from rsb_maniskill.version import BENCHMARK_VERSION, UNVERSIONED, benchmark_label, code_commit, package_version


@dataclass
class GenerateSummary:
    path: Path | None
    requested: int
    completed: int
    failures: list[dict]
    skipped_questions: list[int]
    interrupted: str | None
    errors: list[str]
    wall_time: float
    plan_time: float
    sim_time: float
    kept_steps: int
    resume_dir: Path | None = None  # an interrupted run's finished demos, which the same command continues from
    already: bool = False  # the output was there, complete, from the same request: nothing was run

    @property
    def exit_code(self) -> int:
        if self.interrupted:
            return 128 + int(signal.Signals[self.interrupted])
        return 1 if self.errors else 0  # questions without a demo are listed, not an error


def rsb_header(cfg: GenerateConfig, pool_size: int, num_procs: int, requested: int, summaries: list[dict]) -> dict:
    """Top-level ``rsb`` block of the dataset json: how it was made, what failed and why."""
    completed = sum(s["kept"] for s in summaries)
    errors = [s["error"] for s in summaries if s["error"]]
    return dict(rsb=dict(
        env_id=cfg.env_id, split=cfg.split, pool_size=pool_size, obs_mode=cfg.obs_mode,
        mode="questions" if cfg.questions is not None else "seeds", questions=cfg.questions,
        seed_start=cfg.seed_start, shard=f"{cfg.shard[0]}/{cfg.shard[1]}", num_procs=num_procs,
        max_attempts=cfg.max_attempts, requested=requested, completed=completed,
        complete=completed == requested and not errors,
        interrupted=next((s["interrupted"] for s in summaries if s["interrupted"]), None),
        expert=cfg.expert, env_kwargs_extra=cfg.env_kwargs, benchmark_version=BENCHMARK_VERSION,
        rsb_version=package_version(), code_commit=code_commit(),
        failures=sorted((f for s in summaries for f in s["failures"]), key=lambda f: f["seed"]),
        skipped_questions=sorted(q for s in summaries for q in s["skipped_questions"]),
    ))


def combine_rsb_blocks(blocks: list[dict | None]) -> dict | None:
    """One ``rsb`` block for merged shards: counts summed, failures and skipped questions joined.
    ValueError when the shards are demos of two benchmark versions (their episodes differ)."""
    if not blocks or any(b is None for b in blocks):
        return None
    versions = sorted({b.get("benchmark_version") or UNVERSIONED for b in blocks})
    if len(versions) > 1:
        raise ValueError(f"cannot merge demos of {' and '.join(map(benchmark_label, versions))}: their episodes "
                         "differ (docs/versions.md)")
    out = {k: v for k, v in blocks[0].items() if k not in ("shard", "num_procs")}
    out["shards"] = [b.get("shard") for b in blocks]
    for key in ("requested", "completed"):
        out[key] = sum(b.get(key, 0) for b in blocks)
    out["complete"] = all(b.get("complete", False) for b in blocks)
    out["interrupted"] = next((b["interrupted"] for b in blocks if b.get("interrupted")), None)
    out["failures"] = sorted((f for b in blocks for f in b.get("failures", [])), key=lambda f: f["seed"])
    out["skipped_questions"] = sorted(q for b in blocks for q in b.get("skipped_questions", []))
    return out


def describe(summary: GenerateSummary, errors: bool = True) -> str:
    """Human summary printed at the end of ``rsb generate`` (``errors``: with its error lines, which
    the command prints on stderr instead)."""
    lines = []
    tried = summary.completed + len(summary.failures)
    if summary.already:
        return (f"{summary.path} holds the {summary.completed} demos of this request already (complete); nothing to "
                "do (--overwrite makes them again)")
    if summary.path:
        lines.append(f"wrote {summary.completed} demos to {summary.path} (+ {summary.path.with_suffix('.json').name})")
    elif summary.interrupted or summary.resume_dir:
        lines.append("no output file yet")
    else:
        lines.append("no demos completed; no output written")
    if tried:
        lines.append(f"{tried} episodes tried, {len(summary.failures)} failed "
                     f"({summary.completed / tried:.0%} kept), {summary.wall_time:.1f} s")
    reasons = Counter(f["reason"].split(":")[0] if f["reason"].startswith("error") else f["reason"]
                      for f in summary.failures)
    if reasons:
        lines.append("failure reasons: " + ", ".join(f"{r} x{c}" for r, c in reasons.most_common()))
    if summary.skipped_questions:
        lines.append(f"{len(summary.skipped_questions)} questions got no demo after --max-attempts seeds: "
                     f"{summary.skipped_questions[:20]}{' ...' if len(summary.skipped_questions) > 20 else ''}")
    if summary.interrupted:
        where = f" in {summary.resume_dir}" if summary.resume_dir else ""
        lines.append(f"interrupted by {summary.interrupted}: kept the {summary.completed} finished demos of "
                     f"{summary.requested} requested{where}; rerun the same command to continue")
    for err in summary.errors if errors else ():
        lines.append(f"error: {err}")
    return "\n".join(lines)
