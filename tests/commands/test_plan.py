"""`rsb plan`: the episodes a claim needs, as ``stats.plan_paired`` / ``plan_unpaired`` / ``plan_scenes``
compute them (their power is checked afresh in tests/evaluation/test_power.py), rates in one unit, and a
one-line refusal (or a bounded answer) for every odd input, in bounded time."""
from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.commands.plan import PlanError, parse_rates
from rsb_maniskill.evaluation.stats import plan_paired, plan_scenes, plan_unpaired

DOCS = Path(__file__).resolve().parents[2] / "docs" / "evaluation.md"


def test_plan_prints_the_paired_unpaired_and_follow_episodes(capsys):
    assert main(["plan", "0.1", "0.3", "--variants", "4", "--icc", "0.8"]) == 0
    out = capsys.readouterr().out
    paired, unpaired = plan_paired(0.1, 0.3), plan_unpaired(0.1, 0.3)
    assert "10.0 % from 30.0 %" in out and f"McNemar's exact test): {paired.episodes:,} episodes (power" in out
    assert f"two-proportion z test): {unpaired.episodes:,} episodes" in out
    follow = plan_scenes(0.1, 0.3, size=4, counted=3, icc=0.8)
    line = next(ln for ln in out.splitlines() if ln.startswith("- counterfactual scenes of 4 variants"))
    assert "follow over the 3 changed ones" in line
    assert f"{follow.scenes:,} scenes = {follow.episodes:,} episodes" in line
    assert f"{paired.episodes:,} scenes = {4 * paired.episodes:,} episodes" in out  # ICC 1: a scene counts once
    assert follow.scenes < paired.episodes  # variants that are not all alike add information
    assert "--levels" not in out and "perturbed" not in out


def test_the_docs_plan_block_is_a_real_run(capsys):
    """docs/evaluation.md shows one command and its output: run that command here and compare."""
    text = DOCS.read_text()
    block = re.search(r"```bash\n(rsb plan [^\n]*)\n```\n\n```text\n(.*?)```", text, re.S)
    assert block, "docs/evaluation.md: no `rsb plan` command followed by its output block"
    assert main(block.group(1).split()[1:]) == 0
    assert capsys.readouterr().out == block.group(2)


@pytest.mark.parametrize("argv, words", [
    (["0.3", "0.3"], "tells a rate from itself"),
    (["0.3", "abc"], "'abc' is not a rate"),
    (["0.3", "nan"], "'nan' is not a rate"),
    (["0.3", "inf%"], "'inf%' is not a rate"),
    (["30%", "140%"], "between 0 and 1"),
    (["0.3", "-0.2"], "between 0 and 1"),
    (["1", "2"], "mix a fraction with a percent"),
    (["1.5", "0.5"], "mix a fraction with a percent"),
    (["0.3", "40%"], "mix a fraction with a percent"),
    (["0.3", "0.4", "--icc", "2"], "--icc 2"),
    (["0.3", "0.4", "--icc", "-0.1"], "--icc -0.1"),
    (["0.3", "0.4", "--alpha", "1e-300"], "--alpha 1e-300"),
    (["0.3", "0.4", "--alpha", "0.9"], "--alpha 0.9"),
    (["0.3", "0.4", "--power", "0.01"], "--power 0.01"),
    (["0.3", "0.4", "--power", "1"], "--power 1"),
    (["0.3", "0.4", "--variants", "0"], "--variants 0"),
    (["0.3", "0.4", "--variants", "1000"], "--variants 1000"),
])
def test_plan_refuses_what_is_not_a_rate_or_a_setting_in_one_line(argv, words, capsys):
    assert main(["plan", *argv]) == 2, argv
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1 and err.startswith("rsb plan: error:"), err


@pytest.mark.parametrize("argv", [
    ["0.5", "0.51"], ["0.5", "0.5000001"], ["0", "1"], ["0", "0.001"], ["0.3", "0.4", "--icc", "1"],
    ["0.3", "0.4", "--icc", "0"], ["0.2", "0.6", "--icc", "0.9999999"], ["0.3", "0.4", "--variants", "10"],
    ["0.3", "0.35", "--alpha", "0.0001", "--power", "0.99"],
])
def test_every_odd_input_gets_an_answer_and_a_bounded_one(argv, capsys):
    """The issue's odd inputs: an answer (a difference too small says so, bounded at a million episodes),
    never minutes of computing or a traceback. A generous guard against hangs, not a speed figure: the
    figures are benchmarks/plan_inputs.py's."""
    start = time.monotonic()
    assert main(["plan", *argv]) == 0
    out = capsys.readouterr().out
    assert time.monotonic() - start < 60, argv
    assert out.startswith("To tell") and re.search(r"episodes", out), out
    if argv[:2] == ["0.5", "0.5000001"]:
        assert out.count("more than 1,000,000 episodes") == 4


@pytest.mark.parametrize("a, b, value", [("0.3", "0.4", (0.3, 0.4)), ("30%", "40%", (0.3, 0.4)),
                                         ("30", "40", (0.3, 0.4)), ("1", "0", (1.0, 0.0)), ("0", "5%", (0, 0.05)),
                                         ("100%", "50", (1.0, 0.5))])
def test_rates_are_all_fractions_or_all_percents(a, b, value):
    assert parse_rates(a, b) == pytest.approx(value)


def test_a_mix_of_units_is_refused():
    for a, b in (("1", "2"), ("1.5", "0.5"), ("0.3", "40%"), ("50%", "1")):
        with pytest.raises(PlanError, match="one unit"):
            parse_rates(a, b)
