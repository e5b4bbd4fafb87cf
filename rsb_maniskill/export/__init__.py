"""Exports of RSB demonstrations to other ecosystems' formats (LeRobot)."""
