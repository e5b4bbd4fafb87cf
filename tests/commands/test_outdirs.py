"""Output directories (rsb_maniskill/outdirs.py, a root leaf the commands use): made with their parents,
proven writable without leaving a file behind, and an --out that cannot be a directory fails at once."""
from __future__ import annotations

import pytest

from rsb_maniskill.outdirs import probe_writable, writable_dir


def test_writable_dir_makes_parents_and_leaves_nothing(tmp_path):
    out = writable_dir(tmp_path / "a" / "b")
    assert out == tmp_path / "a" / "b" and out.is_dir()
    assert list(out.iterdir()) == []
    assert writable_dir(str(out)) == out  # again: it exists already


def test_a_path_under_a_file_fails_before_any_work(tmp_path):
    (tmp_path / "results.txt").write_text("kept")
    with pytest.raises(OSError):
        writable_dir(tmp_path / "results.txt" / "run")
    with pytest.raises(OSError):
        probe_writable(tmp_path / "missing")
    assert (tmp_path / "results.txt").read_text() == "kept"
