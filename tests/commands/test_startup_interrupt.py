"""Ctrl-C while ``rsb`` starts (the package's import, before ``cli.main`` runs) ends it as
``cli.main`` does: "rsb: interrupted", exit 130, no traceback; a library user's Ctrl-C, and a
worker's, are left as Python has them (rsb_maniskill/startup.py)."""
from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from rsb_maniskill import startup


@pytest.mark.parametrize("orig_argv, command", [
    (["python", "/venv/bin/rsb", "eval"], True),  # the console script
    (["python", "-m", "rsb_maniskill.cli", "eval"], True),
    (["python", "-X", "dev", "-m", "rsb_maniskill.cli"], True),
    (["python", "-c", "import rsb_maniskill"], False),  # a library user
    (["python", "-m", "pytest"], False),
    (["python", "-c", "from multiprocessing.spawn import spawn_main; spawn_main()", "--multiprocessing-fork"],
     False),  # a spawned worker: given the parent's sys.argv, never its orig_argv
    (["python", "-m"], False),
])
def test_only_the_command_itself_is_guarded(monkeypatch, orig_argv, command):
    monkeypatch.setattr(sys, "orig_argv", orig_argv)
    monkeypatch.setattr(sys, "argv", ["/venv/bin/rsb"])  # what a spawned worker of `rsb` is given
    assert startup.is_command() is command


def test_guard_then_release_hand_ctrl_c_back(monkeypatch):
    monkeypatch.setattr(sys, "orig_argv", ["python", "/venv/bin/rsb"])
    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        startup.guard()
        assert signal.getsignal(signal.SIGINT) is startup._interrupted
        startup.release()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        monkeypatch.setattr(sys, "orig_argv", ["python", "-c", "pass"])
        startup.guard()  # not the command: Python's own Ctrl-C stays
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)


_INTERRUPT_MID_IMPORT = """
import os, signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)      # as from a terminal (not a background job)
sys.orig_argv = [sys.executable, "-m", "rsb_maniskill.cli"]   # as `python -m rsb_maniskill.cli` starts
import rsb_maniskill.startup as s                             # what the package does first
s.guard()
os.kill(os.getpid(), signal.SIGINT)                           # Ctrl-C while the rest still imports
import rsb_maniskill.cli                                      # never reached
print("not interrupted")
"""


def test_ctrl_c_during_the_import_is_one_line_and_130():
    res = subprocess.run([sys.executable, "-c", _INTERRUPT_MID_IMPORT], capture_output=True, text=True, timeout=120)
    assert res.returncode == startup.INTERRUPTED, res.stderr[-2000:]
    assert res.stderr == "rsb: interrupted\n" and "not interrupted" not in res.stdout


def test_the_command_releases_the_guard_and_catches_ctrl_c_itself():
    """From cli.main on, Ctrl-C is a KeyboardInterrupt that main turns into its line (its cleanup runs)."""
    code = ("import os, signal, sys\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "sys.orig_argv = [sys.executable, '-m', 'rsb_maniskill.cli']\n"
            "import rsb_maniskill.startup as s\ns.guard()\nfrom rsb_maniskill import cli\n"
            "cli.main(['--version'])\nprint(signal.getsignal(signal.SIGINT) is signal.default_int_handler)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip().endswith("True"), res.stdout + res.stderr[-2000:]
