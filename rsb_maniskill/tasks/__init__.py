"""ManiSkill tasks of the pack (registered with ManiSkill on import)."""
from rsb_maniskill.registration import drop_lazy_entries

drop_lazy_entries()  # ManiSkill's register_env below writes the gymnasium entries itself

from rsb_maniskill.tasks.answer_selection import AnswerSelectionEnv  # noqa: E402
from rsb_maniskill.tasks.tabletop import TableTopEnv  # noqa: E402

__all__ = ["AnswerSelectionEnv", "TableTopEnv"]
