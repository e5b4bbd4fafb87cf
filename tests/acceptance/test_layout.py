"""The tests' layout holds: tests/<room>/ mirrors rsb_maniskill/<room>/ (acceptance tests of the whole pack
apart, shared helpers in tests/helpers/), basenames unique (pytest imports them by basename: no __init__.py),
and no test module imports another (what tests share lives in tests/helpers/). Prints, without failing, the
modules of rsb_maniskill that no test names (``pytest -s tests/acceptance/test_layout.py``)."""
from __future__ import annotations

import ast
import re
from collections import Counter
from pathlib import Path

import rsb_maniskill

TESTS = Path(__file__).resolve().parents[1]
PACKAGE = Path(rsb_maniskill.__file__).resolve().parent
APART = {"acceptance"}  # tests of the whole pack, not of one room
NOT_TESTS = {"helpers", "fixtures"}  # shared modules; data


def _rooms() -> set[str]:
    """The package rooms: rsb_maniskill's subpackages."""
    return {p.parent.name for p in PACKAGE.glob("*/__init__.py")}


def _test_files() -> list[Path]:
    return sorted(TESTS.rglob("test_*.py"))


def _python_files() -> list[Path]:
    """Every Python file of the tests but the fixture data's own scripts."""
    return sorted(p for p in TESTS.rglob("*.py") if "fixtures" not in p.relative_to(TESTS).parts)


def test_every_test_file_lives_in_a_room_folder():
    misplaced = [str(p.relative_to(TESTS)) for p in _test_files()
                 if len(p.relative_to(TESTS).parts) != 2 or p.parent.name not in _rooms() | APART]
    assert not misplaced, f"test files outside tests/<room>/ (a room is a subpackage of rsb_maniskill): {misplaced}"
    folders = {p.name for p in TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "__"))}
    assert folders - _rooms() - APART - NOT_TESTS == set(), "a folder of tests/ that names no package room"
    assert not list(TESTS.rglob("__init__.py")), "tests/ has no packages: pytest imports test modules by basename"


def test_basenames_are_unique():
    names = Counter(p.stem for p in _python_files() if p.name != "conftest.py")
    assert [n for n, k in names.items() if k > 1] == []


def test_no_test_module_imports_another():
    test_modules = {p.stem for p in _test_files()}
    offenders = []
    for path in _python_files():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            offenders += [f"{path.relative_to(TESTS)} imports {n}" for n in names if n.split(".")[0] in test_modules]
    assert offenders == [], "move what tests share into tests/helpers/"


def _package_modules() -> list[str]:
    out = []
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = p.relative_to(PACKAGE.parent).with_suffix("").parts
        out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def _named_modules() -> set[str]:
    """Every rsb_maniskill module a test or helper names: imported (``from a.b import c`` names a.b and
    a.b.c), run (``-m a.b``) or written out (``"a.b:attr"``)."""
    named = set()
    for path in _python_files():
        text = path.read_text(encoding="utf-8")
        named |= set(re.findall(r"rsb_maniskill(?:\.\w+)*", text))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("rsb_maniskill"):
                named |= {f"{node.module}.{a.name}" for a in node.names}
    return named


def test_untested_modules_are_listed():
    modules, named = _package_modules(), _named_modules()
    # a package counts as named when one of its modules is (importing that one runs the package's __init__)
    unnamed = [m for m in modules if m not in named and not any(n.startswith(m + ".") for n in named)]
    print(f"\n{len(unnamed)} of {len(modules)} modules of rsb_maniskill named by no test:")
    for m in unnamed:
        print(f"  {m}")
    assert len(unnamed) < len(modules) and "rsb_maniskill" not in unnamed  # the scan reads the tests at all
