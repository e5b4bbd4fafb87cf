"""ManiSkill tasks of the pack. ``rsb_maniskill.registration.load_simulator`` registers them with
ManiSkill under every RSB id (at the first ``gym.make``); the classes themselves touch no registry."""
from rsb_maniskill.tasks.answer_selection import AnswerSelectionEnv
from rsb_maniskill.tasks.tabletop import TableTopEnv

__all__ = ["AnswerSelectionEnv", "TableTopEnv"]
