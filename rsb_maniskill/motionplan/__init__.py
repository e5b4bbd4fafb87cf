"""Scripted motion-planning expert (mplib) for the RSB answer-selection task."""
from rsb_maniskill.motionplan.expert import ExpertResult, ScriptedExpert
from rsb_maniskill.motionplan.planner import ArmPlanner, get_planner

__all__ = ["ArmPlanner", "ExpertResult", "ScriptedExpert", "get_planner"]
