"""Shared fixtures. Question data: the real GSM8K / MMLU-Pro files when ``RSB_DATA_DIR`` names them (CI
sets it to the shared copies), else the small fixtures written for the tests, so that no test that
only needs *some* questions skips on a machine without the datasets."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

FIXTURE_DATA = Path(__file__).resolve().parent / "fixtures" / "semantic_data"


@pytest.fixture
def question_data(monkeypatch) -> Path:
    """The data directory in use; sets ``RSB_DATA_DIR`` (also for subprocesses) when unset."""
    if os.environ.get("RSB_DATA_DIR"):
        return Path(os.environ["RSB_DATA_DIR"])
    monkeypatch.setenv("RSB_DATA_DIR", str(FIXTURE_DATA))
    return FIXTURE_DATA
