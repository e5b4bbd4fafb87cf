"""Shortcut audit of RSB option sets (`rsb audit`): can a guesser that never solves the question
beat chance? Simulator-free, like the semantic engine it audits. See docs/semantic.md."""
from __future__ import annotations

from rsb_maniskill.audit.guessers import Guesser, credit, named_guessers
from rsb_maniskill.audit.lexical import LexicalResult, lexical_probe
from rsb_maniskill.audit.readers import NumberReachabilityReader, Reader, SimilarityReader, default_readers, load_reader
from rsb_maniskill.audit.reference import ReaderResult, lift
from rsb_maniskill.audit.run import MARGIN, GuesserResult, SuiteAudit, ambiguous_sets, audit_specs, audit_suite
from rsb_maniskill.audit.twins import TwinFailure, twin_failures

__all__ = ["MARGIN", "Guesser", "GuesserResult", "LexicalResult", "NumberReachabilityReader", "Reader", "ReaderResult",
           "SimilarityReader", "SuiteAudit", "TwinFailure", "ambiguous_sets", "audit_specs", "audit_suite", "credit",
           "default_readers", "lexical_probe", "lift", "load_reader", "named_guessers", "twin_failures"]
