"""The package's floors, as its imports draw them: rooms, arrows, floors, cycles and module sizes.

    python scripts/architecture.py              # the figures (docs/architecture.md quotes them)
    python scripts/architecture.py --rooms      # every room with its floor and the rooms it imports
    python scripts/architecture.py --png docs/images/architecture.png   # the picture

A *room* is a sub-package, or a top-level module of ``rsb_maniskill``; an *arrow* runs from a room
to each room it imports (any import, function-level ones included, as grimp and import-linter see
them); a room's *floor* is one more than the highest floor it imports, so the leaves stand on floor 1
and the commands on top. The contracts that keep it so are import-linter's (``pyproject.toml``,
``make lint``); this script only measures and draws.
"""
from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import grimp

PACKAGE = "rsb_maniskill"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE


def room_of(module: str, packages: set[str]) -> str:
    """The deepest package holding ``module`` (itself when it is one), or the top-level module."""
    parts = module.split(".")
    if module in packages:
        return module
    return ".".join(parts[:-1]) if len(parts) > 2 else module


def house(graph: grimp.ImportGraph) -> tuple[dict[str, set[str]], list[list[str]]]:
    """The arrows between rooms, and the import cycles between modules (strongly connected sets)."""
    modules = {m for m in graph.modules if m.startswith(PACKAGE + ".")}
    packages = {m for m in modules if (ROOT.parent / m.replace(".", "/") / "__init__.py").exists()}
    arrows: dict[str, set[str]] = defaultdict(set)
    for m in modules:
        arrows[room_of(m, packages)]
        for n in graph.find_modules_directly_imported_by(m):
            if n in modules and room_of(n, packages) != room_of(m, packages):
                arrows[room_of(m, packages)].add(room_of(n, packages))
    # The entry point imports its commands by name (rsb_maniskill.cli._COMMAND_MODULES): real arrows too.
    from rsb_maniskill.cli import _COMMAND_MODULES

    arrows[f"{PACKAGE}.cli"] |= {room_of(m, packages) for m in _COMMAND_MODULES}
    return dict(arrows), cycles({m: {n for n in graph.find_modules_directly_imported_by(m) if n in modules}
                                 for m in modules})


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected sets of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def floors(arrows: dict[str, set[str]]) -> dict[str, int]:
    """Floor of each room: 1 + the highest floor it imports (rooms in a cycle share the cycle's floor)."""
    memo: dict[str, int] = {}

    def floor(r: str, seen: frozenset[str]) -> int:
        if r not in memo:
            below = [floor(s, seen | {r}) for s in arrows[r] if s not in seen | {r}]
            memo[r] = 1 + max(below, default=0)
        return memo[r]

    return {r: floor(r, frozenset()) for r in arrows}


def upward(arrows: dict[str, set[str]], floor: dict[str, int]) -> list[tuple[str, str]]:
    """Arrows that do not run down: to a room on the same floor or above (only a cycle makes them)."""
    return sorted((a, b) for a, targets in arrows.items() for b in targets if floor[b] >= floor[a])


def sizes(limit: int = 8) -> list[tuple[int, str]]:
    lines = ((sum(1 for _ in p.open()), str(p.relative_to(ROOT.parent))) for p in ROOT.rglob("*.py"))
    return sorted(lines, reverse=True)[:limit]


def reduced(arrows: dict[str, set[str]]) -> dict[str, set[str]]:
    """The arrows no longer path implies (the transitive reduction), so the picture stays readable."""
    def reach(r: str, seen: set[str]) -> set[str]:
        for s in arrows[r]:
            if s not in seen:
                seen.add(s)
                reach(s, seen)
        return seen

    return {a: {b for b in bs if not any(b in reach(c, set()) for c in bs - {b})} for a, bs in arrows.items()}


def draw(arrows: dict[str, set[str]], floor: dict[str, int], path: Path) -> None:
    """The floors as a picture: one row a floor, the commands on top; grey arrows are the transitive
    reduction (an arrow implied by a longer path is left out)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows: dict[int, list[str]] = defaultdict(list)
    for r in sorted(arrows):
        rows[floor[r]].append(r)
    top = max(rows)
    width = max(len(v) for v in rows.values())
    fig = Figure(figsize=(2.1 * width + 1, 1.05 * top + 0.6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    at = {}
    for f, names in rows.items():
        for i, r in enumerate(names):
            at[r] = ((i + 0.5) * width / len(names), f)
    for a, targets in reduced(arrows).items():
        for b in targets:
            (x0, y0), (x1, y1) = at[a], at[b]
            ax.annotate("", (x1, y1 + 0.18), (x0, y0 - 0.18),
                        arrowprops=dict(arrowstyle="-|>", color="#b9c2cc", lw=0.6, shrinkA=0, shrinkB=0))
    for r, (x, y) in at.items():
        ax.text(x, y, r.removeprefix(PACKAGE + "."), ha="center", va="center", fontsize=8,
                bbox=dict(boxstyle="round,pad=0.3", fc="#eef4fb" if "cli" not in r else "#fdeedc", ec="#5d6875"))
    for f in rows:
        ax.text(-0.05, f, f"floor {f}", ha="right", va="center", fontsize=8, color="#5d6875")
    ax.set_xlim(-0.9, width + 0.1)
    ax.set_ylim(0.4, top + 0.6)
    ax.axis("off")
    fig.savefig(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", action="store_true", help="list every room with its floor and its arrows")
    parser.add_argument("--png", type=Path, default=None, help="draw the floors into this PNG")
    args = parser.parse_args()
    arrows, module_cycles = house(grimp.build_graph(PACKAGE))
    floor = floors(arrows)
    up = upward(arrows, floor)
    print(f"rooms {len(arrows)}, floors {max(floor.values())}, arrows {sum(map(len, arrows.values()))}, "
          f"import cycles {len(module_cycles)}, arrows up {len(up)}")
    for group in module_cycles:
        print("cycle: " + " -> ".join(group))
    for a, b in up:
        print(f"arrow up: {a} -> {b}")
    print("largest modules: " + ", ".join(f"{p} {n}" for n, p in sizes()))
    if args.rooms:
        for r in sorted(arrows, key=lambda r: (-floor[r], r)):
            print(f"{floor[r]:>2} {r} -> {', '.join(sorted(arrows[r])) or '-'}")
    if args.png:
        draw(arrows, floor, args.png)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
