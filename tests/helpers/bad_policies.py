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
    "complex": (np.zeros((2, 14), dtype=complex), "act returned complex actions (dtype complex128)"),
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
            import multiprocessing
            import os
            import signal
            import time

            if multiprocessing.parent_process() is None:
                raise KeyboardInterrupt
            # in rsb eval's worker process: Ctrl-C reaches the main process, which stops this worker
            marker = os.environ.get("RSB_TEST_INTERRUPT_MARKER")
            if marker and os.path.exists(marker):
                return
            if marker:
                open(marker, "w").close()
            os.kill(os.getppid(), signal.SIGINT)
            time.sleep(60)  # the main process's SIGTERM ends this wait


class Exits(Returns):
    """Ends the process from ``where`` ("act", "reset" or "factory") with ``how``: "sys.exit" (code 0),
    "os._exit" (code 3) or "SystemExit" (code 5), or raises "KeyboardInterrupt" with no Ctrl-C sent; in act
    only after ``after`` calls (finished episodes first)."""

    def __init__(self, how: str = "sys.exit", where: str = "act", after: int = 0) -> None:
        super().__init__("width")
        self.output = np.zeros((1, 14), dtype=np.float32)
        self.how, self.where, self.after, self.calls = how, where, after, 0
        if where == "factory":
            self.leave()

    def leave(self) -> None:
        import os
        import sys

        if self.how == "os._exit":
            os._exit(3)
        if self.how == "SystemExit":
            raise SystemExit(5)
        if self.how == "KeyboardInterrupt":
            raise KeyboardInterrupt
        sys.exit(0)

    def reset(self, instruction, obs) -> None:
        if self.where == "reset":
            self.leave()

    def act(self, obs):
        self.calls += 1
        if self.where == "act" and self.calls > self.after:
            self.leave()
        return self.output


def exits(how: str = "sys.exit", where: str = "act", after: int = 0) -> Exits:
    return Exits(how, where, after)


class Hangs(Exits):
    """Never returns from ``where`` (a sleep, or a busy C-level wait with ``how="c"``)."""

    def leave(self) -> None:
        import time

        if self.how == "c":  # a blocking call in native code: no Python signal handler runs inside
            import ctypes

            ctypes.CDLL(None).sleep(3600)
        time.sleep(3600)


def hangs(how: str = "sleep", where: str = "act", after: int = 0) -> Hangs:
    return Hangs(how, where, after)


class Draws:
    """The ``random`` reference policy (tiny actions) that says what it drew: each ``act`` returns its
    chunk with a text naming a digest of it, so that a record shows the episode's draws. With
    ``reseed=False`` it ignores the episode seed, as a policy whose one generator is seeded at
    construction does: its episodes then depend on K, P and order (the flaw the tests must catch)."""

    log: dict = {}  # episode seed -> the digests of the chunks drawn in it (this process's instances)

    def __init__(self, reseed: bool = True, talk: bool = True) -> None:
        from rsb_maniskill.policies.reference import RandomPolicy

        self.inner = RandomPolicy(np.full(14, -1e-3), np.full(14, 1e-3), chunk_size=5)
        self.reseed, self.talk, self.seed = reseed, talk, None

    def reset(self, instruction, obs, seed=None) -> None:
        self.seed = seed
        self.inner.reset(instruction, obs, seed=seed if self.reseed else None)

    def act(self, obs):
        import hashlib

        chunk = self.inner.act(obs)
        said = f"drew {hashlib.sha256(chunk.tobytes()).hexdigest()[:12]}"
        Draws.log.setdefault(self.seed, []).append(said)
        return {"actions": chunk, "text": said} if self.talk else chunk


def draws(reseed: bool = True) -> Draws:
    return Draws(reseed)


class DeafHangs(Exits):
    """Blocks in ``act`` after ``after`` calls with SIGINT and SIGTERM ignored (a native library
    that masks them): only SIGKILL ends it."""

    def leave(self) -> None:
        import os
        import signal
        import time

        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        marker = os.environ.get("RSB_TEST_BLOCKED_MARKER")  # the test signals once this is there
        if marker:
            open(marker, "w").close()
        while True:
            time.sleep(3600)


def deaf_hangs(after: int = 0) -> DeafHangs:
    return DeafHangs("sleep", "act", after)


class ActFails(Returns):
    """An ``act``-only policy whose ``act`` raises in episode ``on`` (its seed, as given at reset)."""

    def __init__(self, on: int) -> None:
        super().__init__("width")
        self.output = np.zeros((1, 14), dtype=np.float32)
        self.on, self.seed = on, None

    def reset(self, instruction, obs, seed=None) -> None:
        self.seed = seed

    def act(self, obs):
        if self.seed == self.on:
            raise RuntimeError(f"no action for seed {self.seed}")
        return self.output


def act_fails(on: int) -> ActFails:
    return ActFails(on)


def lingers(task, emit):
    """A worker target whose process does not exit after its work: a non-daemon thread that sleeps
    (a policy's background thread left running)."""
    import threading
    import time

    threading.Thread(target=time.sleep, args=(3600,), daemon=False).start()
    emit(task)
    return task
