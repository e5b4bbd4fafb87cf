"""Adapters to other frameworks' tools: ``lerobot_env`` (LeRobot; imports nothing of LeRobot) and
``vla_eval`` (a vla-eval benchmark class, so importing it imports vla-eval: the ``vla_eval`` extra)."""
