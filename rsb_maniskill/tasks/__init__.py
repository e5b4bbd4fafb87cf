"""ManiSkill tasks of the pack (registered on import)."""
from rsb_maniskill.tasks.answer_selection import AnswerSelectionEnv
from rsb_maniskill.tasks.tabletop import TableTopEnv

__all__ = ["AnswerSelectionEnv", "TableTopEnv"]
