"""K CPU-physics RSB envs in one process, rendered in one call where CUDA rendering exists (env.py)."""
from rsb_maniskill.vector.env import RSBVectorEnv, make_renderer, make_vector_env

__all__ = ["RSBVectorEnv", "make_renderer", "make_vector_env"]
