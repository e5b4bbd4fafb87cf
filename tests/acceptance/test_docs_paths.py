"""Every repository path the pages name exists: README.md and docs/*.md, in prose, code spans, code blocks and
links (with the heading a link's #anchor names). A page that names a moved module, test or script fails here
with the page, the name and where it was looked for.

What counts as a repository path: a name under a tracked top-level folder (`benchmarks/gpu_check.py`,
`tests/acceptance/`), a module path under one of the package's rooms (`evaluation/jobs.py`, `policies/registry.py`,
resolved under `rsb_maniskill/`), such a path with an attribute (`policies/registry.POLICIES`), a dotted
`rsb_maniskill.` name (`rsb_maniskill.sim.render.hold_render_engine`), and a relative link. A bare `name.py`
is not checked (the pages name other projects' files too): name a module by its room (`evaluation/jobs.py`).
Placeholders (`<room>`, `NAME`, `{...}`, `...`) are skipped; globs (`test_faults*.py`) must match a file.
Paths a command writes (`outputs/`, `results/`, `runs/`) are not under a tracked folder: not checked.
"""
from __future__ import annotations

import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "rsb_maniskill"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# Names the pages use for files that are not this repository's, on purpose
ELSEWHERE = {
    "examples/baselines/diffusion_policy": "ManiSkill's baseline (docs/baselines.md names its repository)",
    "scripts/serve_policy.py": "openpi's server script (docs/evaluation.md)",
    "rsb_maniskill/semantic/my_source.py": "the file a user writes to add a suite (docs/tasks.md)",
    "reporting/sections/steps.py": "the worked example of a report section (docs/architecture.md)",
    "reporting/html_report.py": "the largest module before the redesign (docs/architecture.md's history table)",
}


@cache
def tracked() -> tuple[str, ...]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return tuple(out.splitlines())


@cache
def top_folders() -> tuple[str, ...]:
    return tuple(sorted({p.split("/")[0] for p in tracked() if "/" in p}))


@cache
def rooms() -> tuple[str, ...]:
    return tuple(sorted(d.name for d in PACKAGE.iterdir() if d.is_dir() and not d.name.startswith(("_", "."))))


def placeholder(token: str) -> bool:
    parts = re.split(r"[/.]", token)
    return (any(c in token for c in "<>{}") or "..." in token
            or any(len(p) > 1 and p.isupper() for p in parts) or token.endswith("/X"))


def exists(path: Path) -> bool:
    if "*" in path.name or "*" in str(path):
        return any(ROOT.glob(str(path.relative_to(ROOT))))
    return path.exists()


def defines(module: Path, name: str) -> bool:
    """The module (a .py file or a package's __init__) defines or imports ``name``."""
    for candidate in (module.with_suffix(".py"), module / "__init__.py"):
        if candidate.is_file():
            return re.search(rf"\b{re.escape(name)}\b", candidate.read_text(encoding="utf-8")) is not None
    return False


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
    return {slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", text, re.M)}


def problems(page: Path, text: str | None = None) -> list[str]:
    """What the page (or ``text``, read as if it were that page) names that is not there."""
    text = page.read_text(encoding="utf-8") if text is None else text
    found: list[str] = []
    top = "|".join(map(re.escape, top_folders()))
    room = "|".join(map(re.escape, rooms()))
    seen: set[str] = set()

    def check(token: str, path: Path, what: str) -> None:
        if token in seen or placeholder(token) or token in ELSEWHERE:
            return
        seen.add(token)
        if not exists(path):
            found.append(f"{token} ({what}: no {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path})")

    # paths under a tracked top-level folder, anywhere on the page
    for m in re.finditer(rf"(?<![\w./~-])((?:{top})/[\w.*/-]*[\w*/])", text):
        token = m.group(1).rstrip(".")
        if re.search(r"\.(py|md|sh|json|toml|yaml|yml|png|jsonl|txt|html|h5|cfg)$|/$", token) or "." not in token:
            check(token, ROOT / token, "repository path")
    spans = re.findall(r"`([^`\n]+)`", text)
    for span in spans:
        for token in span.split():
            token = token.strip("(),;:'\"")
            # module paths under the package's rooms: evaluation/jobs.py, policies/registry.POLICIES, sections/
            m = re.fullmatch(rf"((?:{room})(?:/[\w*]+)*)(\.py|\.txt|\.json|/|\.([A-Za-z_]\w*)(?:\(\))?)?", token)
            if m and "/" in token and not token.startswith(top_folders()):
                base = PACKAGE / m.group(1)
                if m.group(2) in (".py", ".txt", ".json"):
                    check(token, base.with_suffix(m.group(2)), "package file")
                elif m.group(3):
                    if base.with_suffix(".py").is_file() or (base / "__init__.py").is_file():
                        if not defines(base, m.group(3)) and token not in seen:
                            seen.add(token)
                            found.append(f"{token} ({base.relative_to(ROOT)} defines no {m.group(3)})")
                    else:
                        check(token, base.with_suffix(".py"), "package module")
                else:
                    check(token, base, "package folder")
                continue
            # dotted names of the package: rsb_maniskill.sim.render.hold_render_engine, rsb_maniskill.x:attr
            m = re.fullmatch(r"rsb_maniskill((?:\.\w+)*)(?::(\w+))?", token)
            if m and m.group(1):
                parts = m.group(1).strip(".").split(".")
                module, attr = PACKAGE, m.group(2)
                for i, part in enumerate(parts):
                    if (module / part).is_dir() or (module / f"{part}.py").is_file():
                        module = module / part
                    else:
                        attr = attr or part
                        parts = parts[:i] + (parts[i + 1:] if i + 1 < len(parts) else [])
                        break
                if attr and not defines(module, attr) and token not in seen:
                    seen.add(token)
                    found.append(f"{token} ({module.relative_to(ROOT)} defines no {attr})")
                continue
    # relative links and their anchors
    for m in re.finditer(r"\]\(([^)\s]+)\)", text):
        target = m.group(1)
        if re.match(r"[a-z]+:", target) or target.startswith("//"):
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            found.append(f"{target} (link: no {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest})")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            found.append(f"{target} (link: {dest.name} has no heading #{anchor})")
    return found


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_repository_path_a_page_names_exists(page):
    assert problems(page) == []


def test_the_checker_finds_a_moved_path():
    """What the test would say of a stale page: each kind of name is looked for where it must be."""
    found = problems(ROOT / "docs" / "probe.md", (
        "Run `python benchmarks/no_such_bench.py`; the module `evaluation/policy_error.py` and\n"
        "`policies/registry.NO_SUCH_NAME`, `rsb_maniskill.sim.render.no_such_function`, `semantic/no_such.txt`,\n"
        "[a link](gpu.md#no-such-heading), [another](no_such_page.md). Fine: `evaluation/jobs.py`,\n"
        "`policies/registry.POLICIES`, `benchmarks/results/NAME.json`, `tests/<room>/`, `results/pi05`,\n"
        "`tests/acceptance/test_faults*.py`, [gpu](gpu.md#gpu-figures-measured-and-projected).\n"))
    named = [f.split(" ")[0] for f in found]
    assert named == ["benchmarks/no_such_bench.py", "evaluation/policy_error.py", "policies/registry.NO_SUCH_NAME",
                     "rsb_maniskill.sim.render.no_such_function", "semantic/no_such.txt", "gpu.md#no-such-heading",
                     "no_such_page.md"], found
