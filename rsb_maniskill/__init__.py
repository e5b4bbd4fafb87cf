"""RoboSemanticBench (RSB) as a ManiSkill3 task pack.

``import rsb_maniskill`` registers the ``RSB-*`` environments with gymnasium; the robot and the
tasks (torch, SAPIEN, ManiSkill) load at the first ``gym.make``, so this import, the semantic
engine and the ``rsb`` command line stay light. The robot ``aloha_agilex`` registers with
ManiSkill at ``import rsb_maniskill.agents``, or here when ManiSkill is imported already
(see registration.py).
"""
from rsb_maniskill import startup

startup.guard()  # the `rsb` command only: Ctrl-C during this import ends it quietly (cli.main releases it)
if startup.bare_command():  # `rsb --version` / `--help`: before the suites are read, which loads the plugins
    from rsb_maniskill.plugins import skip_plugins

    skip_plugins()

from rsb_maniskill.registration import register_agent_if_maniskill_loaded, register_envs  # noqa: E402
from rsb_maniskill.sim import render  # noqa: F401,E402  (selects a Vulkan device before SAPIEN starts)
from rsb_maniskill.version import package_version as _package_version  # noqa: E402

register_envs()
register_agent_if_maniskill_loaded()

__version__ = _package_version()  # the package's (pyproject.toml); BENCHMARK_VERSION names the episodes
