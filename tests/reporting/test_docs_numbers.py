"""The docs' counterfactual table (docs/evaluation.md, "Counterfactual scenes") is rendered from the records
of the runs it names (`rsb eval oracle|blind|leftmost --suites RSB-Math-4 RSB-Math-10 -n 20 --instruction
counterfactual -o state`, kept stripped to the fields the table reads in tests/reporting/data/counterfactual/):
every number of it is the report code's, recomputed here, so a change of method cannot leave stale intervals."""
from __future__ import annotations

import json
from pathlib import Path

from rsb_maniskill.reporting.cells import pct, rate_cell
from rsb_maniskill.reporting.sections.counterfactual import counterfactual_table

ROOT = Path(__file__).resolve().parents[2]
RECORDS = Path(__file__).with_name("data") / "counterfactual"
POLICIES = ("oracle", "blind", "leftmost")
HEADER = "| policy | suite | Follow | chance | remap | requestion | Switch | chance | Stuck | chance |"


def rendered_rows() -> list[str]:
    """The table's rows as the docs write them, from the records."""
    rows = []
    for policy in POLICIES:
        records = [json.loads(line) for line in (RECORDS / f"{policy}.jsonl").read_text().splitlines()]
        table = counterfactual_table(records)[f"{policy} (counterfactual)"]
        for suite in [s for s in ("RSB-Math-4", "RSB-Math-10") if s in table]:
            m = table[suite]
            cells = [policy, suite, rate_cell(m.follow), pct(m.chance_follow), rate_cell(m.follow_by_kind["remap"]),
                     rate_cell(m.follow_by_kind["requestion"]), rate_cell(m.switch), pct(m.chance_switch),
                     rate_cell(m.stuck), pct(m.chance_stuck)]
            rows.append("| " + " | ".join(cells) + " |")
    return rows


def docs_rows() -> list[str]:
    """The table's rows in docs/evaluation.md: the lines after its header and rule, up to a blank line."""
    text = (ROOT / "docs" / "evaluation.md").read_text(encoding="utf-8")
    lines = text.split(HEADER, 1)[1].splitlines()[2:]
    return lines[:lines.index("")]


def test_the_docs_counterfactual_table_is_the_reports_on_the_runs_it_names():
    assert docs_rows() == rendered_rows()


def test_the_reference_runs_are_the_docs_commands():
    """Every variant of every scene run and grasped (as the docs say), on the scenes the commands name."""
    text = (ROOT / "docs" / "evaluation.md").read_text(encoding="utf-8")
    for policy in POLICIES:
        records = [json.loads(line) for line in (RECORDS / f"{policy}.jsonl").read_text().splitlines()]
        scenes = {(r["suite_id"], r["seed"]) for r in records}
        assert len(records) == 4 * len(scenes) and all(r["grasped_any"] for r in records), policy
        n = len(scenes) // len({s for s, _ in scenes})
        commands = [line for line in text.splitlines()
                    if line.startswith(f"rsb eval {policy} ") and "--instruction counterfactual" in line]
        assert any(f" -n {n} " in line for line in commands), (policy, n, commands)
