"""ManiSkill tasks of the pack. Each class names the RSB ids it serves above itself
(``@env_ids.serves``); ``rsb_maniskill.registration.load_simulator`` registers them with ManiSkill
under those ids (at the first ``gym.make``). The classes themselves touch no registry."""
from rsb_maniskill.tasks.answer_selection import AnswerSelectionEnv
from rsb_maniskill.tasks.tabletop import TableTopEnv

TASK_CLASSES = (AnswerSelectionEnv, TableTopEnv)

__all__ = ["TASK_CLASSES", "AnswerSelectionEnv", "TableTopEnv"]
