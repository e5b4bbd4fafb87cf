"""Answer targets: what the robot picks (blocks now; everyday objects later)."""
from rsb_maniskill.objects.base import AnswerTargets
from rsb_maniskill.objects.blocks import BLOCK_HALF, Blocks

__all__ = ["AnswerTargets", "BLOCK_HALF", "Blocks"]
