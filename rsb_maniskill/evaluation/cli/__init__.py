"""The evaluation's commands: ``rsb eval`` (``eval.py``), ``rsb backbone`` (``backbone.py``) and ``rsb
report`` (``report.py``), with the argument checks they share (``args.py``).

The top of the evaluation's layers: each module exposes ``register(subparsers)`` for the ``rsb``
dispatcher (``rsb_maniskill/cli.py``) and keeps its heavy imports inside the command. Nothing in the
library below imports these modules.
"""
