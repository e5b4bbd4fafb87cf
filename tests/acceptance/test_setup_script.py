"""scripts/setup.sh installs with uv, which reads no pip.conf: it must hand uv pip's own index
settings, and fall back to pip where uv fails. Its functions run here in bash against fakes."""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

SETUP = Path(__file__).resolve().parents[2] / "scripts" / "setup.sh"


def function(name: str) -> str:
    """The text of the shell function ``name`` in setup.sh."""
    match = re.search(rf"^{name}\(\) {{\n.*?^}}\n", SETUP.read_text(), re.S | re.M)
    assert match, f"scripts/setup.sh has no function {name}"
    return match.group(0)


def fake(path: Path, body: str) -> Path:
    path.write_text("#!/usr/bin/env bash\n" + body)
    path.chmod(0o755)
    return path


def bash(script: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", "set -euo pipefail\n" + script], capture_output=True, text=True,
                          timeout=30)


def test_pips_index_settings_reach_uv(tmp_path):
    config = tmp_path / "config.txt"  # what `pip config list` prints: files, then PIP_* variables
    config.write_text(
        "global.index-url='https://pypi.lab.example/simple'\n"
        "global.extra-index-url='file:///opt/pypi/simple file:///opt/more/simple'\n"
        "global.find-links='/opt/wheels'\n"
        "install.constraint='/etc/pip/constraints.txt'\n"
        "global.trusted-host='pypi.lab.example'\n"
        "global.no-index='false'\n"
        "global.cert='/etc/ssl/certs/ca.crt'\n"
        ":env:.find-links='/opt/wheels'\n"
        ":env:.default-timeout='180'\n")
    res = bash(f"PIP_CONFIG=$(cat {config})\n{function('uv_flags_from_pip')}uv_flags_from_pip")
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [
        "--index-strategy=unsafe-best-match",  # pip's choice: the newest release on any index
        "--index-url=https://pypi.lab.example/simple",
        "--extra-index-url=file:///opt/pypi/simple", "--extra-index-url=file:///opt/more/simple",
        "--find-links=/opt/wheels",  # once, though set in a file and in PIP_FIND_LINKS
        "--constraint=/etc/pip/constraints.txt",
        "--allow-insecure-host=pypi.lab.example"]


def test_no_index_reaches_uv(tmp_path):
    config = tmp_path / "config.txt"
    config.write_text(":env:.no-index='1'\n:env:.find-links='/wheels'\n")
    res = bash(f"PIP_CONFIG=$(cat {config})\n{function('uv_flags_from_pip')}uv_flags_from_pip")
    assert res.stdout.split() == ["--index-strategy=unsafe-best-match", "--no-index", "--find-links=/wheels"]


def test_install_uses_uv_with_the_flags_and_pip_where_uv_fails(tmp_path):
    venv, log = tmp_path / "venv", tmp_path / "calls.log"
    (venv / "bin").mkdir(parents=True)
    pip = fake(tmp_path / "pip", f'echo "pip $*" >> {log}\n')
    uv = fake(venv / "bin" / "uv", f'echo "uv $*" >> {log}\n[ "$UV_WORKS" = 1 ]\n')
    script = (f"VENV={venv}\nPIP='{pip} -m pip'\nUV_FLAGS=(--find-links=/wheels)\n"
              f"{function('install')}install -e '.[dev]'")

    res = bash(f"export UV_WORKS=1\n{script}")
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert log.read_text().splitlines() == [
        f"uv pip install -q --compile-bytecode --python {venv}/bin/python --find-links=/wheels -e .[dev]"]

    log.unlink()
    res = bash(f"export UV_WORKS=0\n{script}")
    assert res.returncode == 0, res.stderr
    assert "uv could not install -e .[dev]; pip does" in res.stderr
    assert log.read_text().splitlines()[1] == "pip -m pip install -q -e .[dev]"

    uv.unlink()  # no uv at all (no wheel for this platform): pip, with the same message
    log.unlink()
    res = bash(f"export UV_WORKS=1\n{script}")
    assert res.returncode == 0 and "pip does" in res.stderr, res.stderr
    assert log.read_text().splitlines() == ["pip -m pip install -q -e .[dev]"]
