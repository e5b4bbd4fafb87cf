"""Scripted motion-planning expert (mplib) for the RSB answer-selection task.

The expert and planner load on first use (they need ManiSkill and mplib), so that the
generation command line and dataset tools import light."""
from __future__ import annotations

from typing import Any

_LAZY = {"ExpertResult": "expert", "ScriptedExpert": "expert", "ArmPlanner": "planner", "get_planner": "planner"}
__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
