"""The README as a user meets it: its first example runs as written on a fresh machine (no question data,
no hub cache), and every `rsb` command it shows parses in today's vocabulary."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"
DATA_FREE = ("RSB-Math-", "RSB-Direct-")  # procedural / diagnostic questions: nothing to download


def first_python_example() -> str:
    """The first ```python block of the README, as a user would paste it."""
    match = re.search(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M)
    assert match, "README.md has no ```python example"
    return match.group(1)


def test_the_first_example_makes_only_data_free_suites():
    made = re.findall(r"gym\.make\(\"([^\"]+)\"", first_python_example())
    assert made, "the first example makes no env"
    assert all(env_id.startswith(DATA_FREE) for env_id in made), made


@pytest.mark.slow
def test_the_first_example_runs_without_any_data(tmp_path):
    env = {**os.environ, "RSB_DATA_DIR": str(tmp_path / "no-data"), "HF_HOME": str(tmp_path / "hf"),
           "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    (tmp_path / "no-data").mkdir()
    script = tmp_path / "example.py"
    script.write_text(first_python_example(), encoding="utf-8")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, env=env,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 2 and "?" in lines[0], out.stdout  # the instruction (a question), then the two flags
    assert re.fullmatch(r"tensor\(\[(True|False)\]\) tensor\(\[(True|False)\]\)", lines[1]), lines[1]


def readme_commands(prefix: str) -> list[list[str]]:
    """Every command line of the README's ```bash blocks that starts with ``prefix`` (continuations
    joined, comments dropped), as argv; lines with a ``...`` placeholder are left out."""
    import shlex

    out = []
    for block in re.findall(r"^```bash\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            argv = shlex.split(line, comments=True)
            if argv[:len(prefix.split())] == prefix.split() and "..." not in argv:
                out.append(argv)
    return out


def test_every_rsb_command_of_the_readme_parses_in_todays_vocabulary(capsys):
    """What the README tells a user to type is accepted by the parser as written, with no
    old-spelling note: a renamed flag cannot leave the README behind."""
    from rsb_maniskill.cli import build_parser

    commands = readme_commands("rsb")
    assert len(commands) >= 10, commands
    for argv in commands:
        try:
            args = build_parser().parse_args(argv[1:])
        except SystemExit as stop:
            pytest.fail(f"README: `{' '.join(argv)}` exits {stop.code} in the parser: {capsys.readouterr().err}")
        assert args.command == argv[1]
        err = capsys.readouterr().err
        assert " is now " not in err, f"README: `{' '.join(argv)}` uses an old spelling: {err}"
