"""`rsb generate -o` is checked as `rsb eval -o` is: a bad obs mode is one usage line (exit 2) before the
simulator or torch loads, against ManiSkill's obs modes as compat.OBS_MODES knows them."""
from __future__ import annotations

import pytest
from cli_probe import probe  # rsb in a process of its own: what a bad -o leaves loaded


@pytest.mark.parametrize("obs_mode, phrase", [
    ("BOGUS", "-o BOGUS: not an obs mode; use one of state, state_dict, none, sensor_data, pointcloud"),
    ("rbg", "(did you mean rgb?)"),
])
def test_a_bad_obs_mode_is_refused_before_the_simulator_loads(obs_mode, phrase, tmp_path):
    found, lines, stderr = probe("generate", "RSB-Direct-4", "-n", "1", "-o", obs_mode,
                                 "--out", str(tmp_path / "demos"))
    assert found == {"status": 2, "heavy": []}, stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("rsb generate: error: ") and phrase in lines[0], stderr
    assert lines[0].endswith("(see rsb generate --help)")
    assert not (tmp_path / "demos").exists()  # nothing written


def test_a_good_obs_mode_parses(capsys):
    from rsb_maniskill.cli import build_parser

    for mode in ("state", "rgb", "rgb+depth", "pointcloud"):
        assert build_parser().parse_args(["generate", "RSB-Direct-4", "-o", mode]).obs_mode == mode
