"""Shortcut audit of RSB option sets (`rsb audit`): can a guesser that never solves the question
beat chance? Simulator-free, like the semantic engine it audits. See docs/semantic.md."""
from __future__ import annotations

from .guessers import Guesser, credit, named_guessers
from .lexical import LexicalResult, lexical_probe
from .readers import NumberReachabilityReader, Reader, SimilarityReader, default_readers, load_reader
from .reference import ReaderResult, lift
from .run import MARGIN, GuesserResult, SuiteAudit, ambiguous_sets, audit_specs, audit_suite
from .twins import TwinFailure, twin_failures

__all__ = ["MARGIN", "Guesser", "GuesserResult", "LexicalResult", "NumberReachabilityReader", "Reader", "ReaderResult",
           "SimilarityReader", "SuiteAudit", "TwinFailure", "ambiguous_sets", "audit_specs", "audit_suite", "credit",
           "default_readers", "lexical_probe", "lift", "load_reader", "named_guessers", "twin_failures"]
