"""The semantic gap end to end, in physics: policies that state the answer (the blind expert that
says the right option and grasps another, the oracle that says it and grasps it), `rsb eval`,
`rsb backbone arithmetic` on the same episodes and `rsb report`."""
from __future__ import annotations

import json

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.policies.reference import ExpertPolicy
from rsb_maniskill.policies.registry import POLICIES, register_policy

SUITE = "RSB-Math-4"
N = "12"


class StatingExpert(ExpertPolicy):
    """The scripted expert (oracle or blind) that states the correct option, in the paper's CoT
    style, with every chunk: a policy whose reasoning is right whatever its arm does."""

    def act(self, obs):
        spec = self.env.unwrapped.episode_specs[0]
        return {"actions": super().act(obs), "text": f"<think> {spec.rationale} </think>"}


@pytest.fixture
def stating_policies(eval_workers_here):
    # registered in this process only (a lambda): the episodes run here, not in rsb eval's worker process
    register_policy("stating-blind", lambda env: StatingExpert(env, blind=True), needs_env=True, single_env=True,
                    obs_mode="state")
    register_policy("stating-oracle", lambda env: StatingExpert(env), needs_env=True, single_env=True,
                    obs_mode="state")
    yield
    POLICIES.pop("stating-blind")
    POLICIES.pop("stating-oracle")


@pytest.mark.slow
def test_table5_and_the_gap_end_to_end(tmp_path, stating_policies):
    out = tmp_path / "res"
    for policy in ("stating-blind", "stating-oracle", "blind"):
        assert main(["eval", policy, "--suites", SUITE, "-n", N, "--out", str(out), "-q"]) == 0
    assert main(["backbone", "arithmetic", "--suites", SUITE, "-n", N, "--out", str(out), "-q"]) == 0
    assert main(["report", str(out)]) == 0

    records = read_records(out / "episodes.jsonl")
    stating = [r for r in records if r["policy"] == "stating-blind"]
    assert all(r["stated_letter"] == r["correct_letter"] for r in stating)  # the text was parsed, every episode
    assert not any("text" in r for r in records if r["policy"] == "blind")
    summary = json.loads((out / "summary.json").read_text())
    t5 = summary["reasoning_following"]
    assert set(t5) == {"stating-blind", "stating-oracle"}
    blind = t5["stating-blind"][SUITE]
    # every wrong-target grasp of the blind expert came with the right option stated
    assert blind["failures"]["stated_wrong"] == blind["failures"]["no_statement"] == 0
    assert blind["n_grasped_failed"] >= 6 and blind["failure_rates"]["stated_right"]["value"] >= 0.9
    oracle = t5["stating-oracle"][SUITE]
    assert oracle["crossing"]["right/right"] == oracle["n_grasped"] >= 11  # stated right, grasped right
    # the gap: arithmetic answers every question; the blind arm picks at random
    gaps = {g["policy"]: g for g in summary["backbone"]["gap"]}
    assert set(gaps) == {"stating-blind", "stating-oracle", "blind"}
    g, row = gaps["blind"], summary["rows"]["blind"]["suites"][SUITE]
    assert g["accuracy"]["value"] == 1.0 and g["n_grasped"] == row["n_grasped"]
    assert g["gap"]["value"] == row["errors"]["wrong_target"] / row["n_grasped"] >= 0.4  # its wrong-block grasps
    assert gaps["stating-oracle"]["gap"]["value"] == 0.0
    assert (out / "summary_gap.png").stat().st_size > 0 and (out / "summary_reasoning.csv").exists()
    md = (out / "summary.md").read_text()
    assert f"### Reasoning following on {SUITE} (%, paper Table 5)" in md and "### The semantic gap" in md
    page = (out / "report.html").read_text()
    assert 'id="reasoning"' in page and 'id="gap"' in page and "data:image/png;base64," in page
