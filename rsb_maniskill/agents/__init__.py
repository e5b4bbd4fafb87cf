"""Robots of the task pack (registered with ManiSkill on import)."""
from rsb_maniskill.agents.aloha import AlohaAgilex, from_aloha14, to_aloha14

__all__ = ["AlohaAgilex", "from_aloha14", "to_aloha14"]
