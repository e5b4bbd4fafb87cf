"""Shortcut audit of RSB option sets (`rsb audit`): can a guesser that never solves the question
beat chance? Simulator-free, like the semantic engine it audits. See docs/semantic.md."""
from __future__ import annotations

from .guessers import Guesser, credit, named_guessers
from .run import MARGIN, GuesserResult, SuiteAudit, ambiguous_sets, audit_specs, audit_suite

__all__ = ["MARGIN", "Guesser", "GuesserResult", "SuiteAudit", "ambiguous_sets", "audit_specs", "audit_suite",
           "credit", "named_guessers"]
