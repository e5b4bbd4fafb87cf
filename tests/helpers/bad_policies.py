"""Policies that misbehave in each way a user policy can, for the error tests (``rsb eval
bad_policies:returns -a what=nan`` with tests/helpers/ on PYTHONPATH; worker processes import them too)."""
from __future__ import annotations

import numpy as np

# what ``returns(what)``'s act gives back, and a phrase of the one-line error it must cause
OUTPUTS = {
    "width": (np.zeros((2, 7), dtype=np.float32), "act returned actions of dim 7"),
    "nan": (np.full((1, 14), np.nan), "act returned NaN or inf actions"),
    "inf": (np.full((3, 14), np.inf), "act returned NaN or inf actions"),
    "none": (None, "act returned None"),
    "string": ("move the red block", "act returned str 'move the red block', not numbers"),
    "empty": (np.zeros((0, 14)), "act returned an empty chunk"),
}


class Returns:
    """Returns ``OUTPUTS[what]`` from every ``act``."""

    def __init__(self, what: str) -> None:
        self.output = OUTPUTS[what][0]

    def reset(self, instruction, obs) -> None:
        pass

    def act(self, obs):
        return self.output


def returns(what: str) -> Returns:
    return Returns(what)


class RaisesInAct(Returns):
    def __init__(self) -> None:
        super().__init__("width")

    def act(self, obs):
        raise RuntimeError("the model is not loaded")


class RaisesInReset(Returns):
    def __init__(self) -> None:
        super().__init__("width")

    def reset(self, instruction, obs) -> None:
        raise KeyError("wrist_camera")


def needs_checkpoint(checkpoint: str, replan_every: int = 10) -> Returns:
    """A factory with a required argument."""
    return Returns("width")


class InterruptsOnce(Returns):
    """Ctrl-C at the start of its second episode, the first time it runs in this process."""

    interrupted = False

    def __init__(self) -> None:
        self.output, self.resets = np.zeros((5, 14), dtype=np.float32), 0

    def reset(self, instruction, obs) -> None:
        self.resets += 1
        if self.resets == 2 and not InterruptsOnce.interrupted:
            InterruptsOnce.interrupted = True
            raise KeyboardInterrupt
