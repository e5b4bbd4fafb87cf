"""Errors raised by the semantic engine.

Two kinds, because callers react differently: missing data is an installation problem
(tell the user how to provide it), malformed data is a data problem (name file and line). A file
that is there but holds no usable question (empty, unreadable, every record left out) is missing
data: the fix is the same, a full copy.
"""
from __future__ import annotations

import os


class SemanticError(Exception):
    """Base class of every error raised by ``rsb_maniskill.semantic``."""


class DataNotFoundError(SemanticError, FileNotFoundError):
    """GSM8K / MMLU-Pro data could be found neither in a data directory nor in the hub cache."""


class EmptyDataError(DataNotFoundError):
    """A GSM8K / MMLU-Pro file (or a question pool) that holds no usable question; the message names
    it and how to replace it (``data.empty_data_error``)."""


class SemanticDataError(SemanticError, ValueError):
    """A data record is malformed; the message names the file and the line (or row)."""

    def __init__(self, path: str | os.PathLike, line: int | None, reason: str) -> None:
        self.path = str(path)
        self.line = line
        self.reason = reason
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {reason}")
