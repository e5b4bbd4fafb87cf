"""The renderer check turns a missing Vulkan device into a clear, actionable error."""
from __future__ import annotations

import pytest

from rsb_maniskill.sim import render


def test_missing_vulkan_device_gives_clear_error(monkeypatch, tmp_path):
    monkeypatch.delenv("RSB_RENDERER_OK", raising=False)
    monkeypatch.setenv("VK_ICD_FILENAMES", str(tmp_path / "no_such_icd.json"))
    with pytest.raises(render.RendererUnavailableError) as err:
        render.ensure_renderer()
    msg = str(err.value)
    assert "lavapipe" in msg and "obs_mode='state'" in msg


def test_working_renderer_passes(monkeypatch):
    monkeypatch.delenv("RSB_RENDERER_OK", raising=False)
    render.ensure_renderer()  # lavapipe (CPU) or a GPU driver must be present where tests run
