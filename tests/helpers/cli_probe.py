"""``rsb`` in a process of its own, as the user's is, reporting its exit status and which heavy
modules (ManiSkill, SAPIEN, torch) it had loaded when it returned: what a refusal that should come
before the simulator loads leaves behind (tests/commands/test_first_hour.py, test_generate_obs_mode.py)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PROBE = """
import json, sys
from rsb_maniskill.cli import main
status = main(sys.argv[1:])
heavy = sorted({m.split(".")[0] for m in sys.modules} & {"mani_skill", "sapien", "torch"})
print(json.dumps({"status": status, "heavy": heavy}))
"""


def probe(*args: str) -> tuple[dict, list[str], str]:
    """``rsb ARGS`` in a fresh interpreter: ({"status", "heavy"}, its stderr lines, its whole stderr)."""
    res = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, cwd=REPO,
                         timeout=120)
    found = json.loads(res.stdout.strip().splitlines()[-1])
    return found, res.stderr.strip().splitlines(), res.stderr
