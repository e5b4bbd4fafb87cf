"""RoboSemanticBench (RSB) as a ManiSkill3 task pack.

``import rsb_maniskill`` registers the ``aloha_agilex`` robot and the ``RSB-*`` environments.
"""
from rsb_maniskill import _render  # noqa: F401  (selects a Vulkan device before SAPIEN starts)
from rsb_maniskill import agents, tasks  # noqa: F401

__version__ = "0.1.0"
