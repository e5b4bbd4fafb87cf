"""`rsb report --compare`'s line per run says what `rsb report` says of it: a run whose results.json
proved its episodes the version's (``pinned``) keeps that verdict where no question data is at hand to
re-check them ("not re-checked: no data"), instead of decaying to "unverified"."""
from __future__ import annotations

import pytest
from verdict_runs import NOT_RECHECKED, episode, run_dir

from rsb_maniskill.cli import main


@pytest.mark.usefixtures("no_data")
def test_compare_keeps_a_pinned_verdict_it_cannot_recheck(tmp_path, capsys):
    a = run_dir(tmp_path / "a", [episode(i) for i in range(3)])  # pinned when it ran
    b = run_dir(tmp_path / "b", [episode(i, policy="other") for i in range(1, 4)], verdict="unverified")
    capsys.readouterr()
    assert main(["report", "--compare", str(a), str(b)]) == 0, capsys.readouterr().err
    lines = capsys.readouterr().out.splitlines()
    line_a = next(line for line in lines if line.startswith(f"{a}: "))
    line_b = next(line for line in lines if line.startswith(f"{b}: "))
    assert "pinned when they were checked before" in line_a and NOT_RECHECKED in line_a, line_a
    assert line_b.startswith(f"{b}: episodes unverified: not checked, no data"), line_b  # never proven: not kept

    assert main(["report", str(a)]) == 0  # the same words as rsb report's own line for the run
    assert capsys.readouterr().out.splitlines()[-1] == line_a.removeprefix(f"{a}: ")
