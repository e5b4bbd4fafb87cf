"""`rsb plan`: the episodes a claim needs, as ``stats.plan_episodes`` computes them (their power is checked by
simulation in tests/evaluation/test_stats.py), and one-line refusals of rates that are not rates."""
from __future__ import annotations

import re

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.commands.plan import parse_rate
from rsb_maniskill.evaluation.stats import plan_episodes, unpaired_sample_size


def test_plan_prints_the_paired_unpaired_and_clustered_episodes(capsys):
    assert main(["plan", "0.1", "30%", "--variants", "4", "--icc", "0.8"]) == 0
    out = capsys.readouterr().out
    paired = plan_episodes(0.1, 0.3)
    assert "10.0 % from 30.0 %" in out and f"{paired.episodes:,} episodes (power" in out
    assert f"{unpaired_sample_size(0.1, 0.3):,} episodes" in out
    clustered = plan_episodes(0.1, 0.3, size=4, icc=0.8)
    line = next(ln for ln in out.splitlines() if ln.startswith("- counterfactual scenes of 4 variants"))
    assert f"{clustered.scenes:,} scenes = {clustered.episodes:,} episodes" in line
    assert f"{paired.episodes:,} scenes = {4 * paired.episodes:,} episodes" in out  # ICC 1: a scene counts once
    assert "perturbed" not in out  # --levels 1: no line
    assert clustered.scenes < paired.episodes  # variants that are not all alike add information


def test_plan_refuses_what_is_not_a_rate_in_one_line(capsys):
    for argv, words in ((["plan", "0.3", "0.3"], "tells a rate from itself"),
                        (["plan", "0.3", "abc"], "'abc' is not a rate"),
                        (["plan", "0.3", "140%"], "between 0 and 1"),
                        (["plan", "0.3", "0.4", "--icc", "2"], "--icc 2"),
                        (["plan", "0.3", "0.4", "--power", "0.01"], "must exceed --alpha")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1 and err.startswith("rsb plan: error:"), err


@pytest.mark.parametrize("text, value", [("0.3", 0.3), ("30%", 0.3), ("30", 0.3), ("1", 1.0), ("0", 0.0)])
def test_rates_are_fractions_or_percents(text, value):
    assert parse_rate(text, "A") == pytest.approx(value)
    assert re.fullmatch(r"[0-9.]+%?", text)
