"""Plugins: installed distributions that add suites, candidate families, policies or wire protocols.

A plugin declares an entry point in the group ``rsb_maniskill.plugins`` naming a module; importing
that module registers what it adds (``register_suite``, ``register_family``, ``register_policy``,
``register_protocol``). The modules are imported once, when the suites are first read (before env ids
exist), so a plugin's suites and families get env ids, gym registrations and commands like the
built-in ones. As LeRobot's ``lerobot_env_*`` plugins: installing the distribution is the switch.
A plugin that fails to import is named on stderr in one line and skipped; nothing else is.
"""
from __future__ import annotations

import importlib
import sys

GROUP = "rsb_maniskill.plugins"
_loaded: list[str] | None = None


def load_plugins() -> list[str]:
    """Import every plugin module once; the names of those that loaded (in entry-point order)."""
    global _loaded
    if _loaded is not None:
        return _loaded
    _loaded = []
    from importlib.metadata import entry_points

    for ep in entry_points(group=GROUP):
        try:
            importlib.import_module(ep.value.partition(":")[0])
        except Exception as err:  # a broken plugin must not take the pack down; it is named, not hidden
            print(f"rsb_maniskill: plugin {ep.name!r} ({ep.value}) failed to load and is skipped: "
                  f"{type(err).__name__}: {err}", file=sys.stderr)
            continue
        _loaded.append(ep.name)
    return _loaded
