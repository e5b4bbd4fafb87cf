"""Adapters to other frameworks\x27 tools (LeRobot): each imports nothing of them at import time."""
