"""``python -m rsb_maniskill.replay``: the command of :mod:`rsb_maniskill.motionplan.replay` (ManiSkill's
``replay_trajectory`` with the RSB envs registered), the same as ``rsb replay``."""
from __future__ import annotations

import sys

from rsb_maniskill.motionplan.replay import main

if __name__ == "__main__":
    sys.exit(main())
