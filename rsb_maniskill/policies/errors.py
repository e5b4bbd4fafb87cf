"""What the evaluation raises when a policy misbehaves, and how the loops name the episode it did it in.

:class:`PolicyError` is the one error type for "the policy misbehaved": its ``reset`` / ``act``
(or their batched forms, or its factory) raised, or it returned what the env cannot take
(``policy.as_chunk`` and the batched checks). The loops run each policy call under
:func:`blame_policy`, which names the policy and the episode and keeps the traceback, so that
``rsb eval`` prints one line (the traceback with ``rsb --debug``), also from a worker process.
"""
from __future__ import annotations

import traceback
from contextlib import contextmanager
from typing import Any, Iterator, Sequence

SHOWN_CHARS = 60  # how much of an unexpected output an error message quotes
# --policy-timeout's default, in rsb eval's workers and in a policy server (rsb serve, the shared one):
# one policy call longer than this is taken for a hang and fails as the policy's error
POLICY_TIMEOUT_S = 300.0


class PolicyError(ValueError):
    """The policy misbehaved: its ``reset`` / ``act`` (or batched forms) raised, or returned what the
    env cannot take. ``str()`` is one line: the policy, the episode (``where``: suite, seed,
    instruction mode) and ``message``; ``detail`` is the traceback (for ``rsb --debug``). It
    pickles whole, so a worker process sends it back as it is."""

    def __init__(self, message: str, *, policy: str | None = None, where: str | None = None,
                 detail: str | None = None) -> None:
        super().__init__(message)
        self.message, self.policy, self.where, self.detail = message, policy, where, detail

    def __str__(self) -> str:
        who = f"policy {self.policy!r}" if self.policy else "the policy"
        return f"{who}{f' on {self.where}' if self.where else ''}: {self.message}"

    def __reduce__(self) -> tuple:
        return _policy_error, (self.message, self.policy, self.where, self.detail)


def _policy_error(message: str, policy: str | None, where: str | None, detail: str | None) -> PolicyError:
    return PolicyError(message, policy=policy, where=where, detail=detail)


SEEDS_LISTED = 4  # an error lists up to this many seeds of a call; more: the first ones and the count


def episode_where(suite_id: str, seeds: Sequence[Any], instruction_mode: str) -> str:
    """How an error names the episode(s) it happened in: ``"RSB-Math-4 seed 10000003 (normal instruction)"``;
    the exact seeds of a call on several envs (a worker's are dealt round-robin: not a range), a range
    only where they are one (``"seeds 10000000..10000063"``)."""
    seeds = list(seeds)
    if len(seeds) == 1:
        shown = f"seed {seeds[0]}"
    elif len(seeds) <= SEEDS_LISTED:
        shown = "seeds " + ", ".join(map(str, seeds))
    elif all(isinstance(s, int) for s in seeds) and seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        shown = f"seeds {seeds[0]}..{seeds[-1]}"
    else:
        shown = f"seeds {', '.join(map(str, seeds[:SEEDS_LISTED]))}, ... ({len(seeds)} seeds)"
    return f"{suite_id} {shown} ({instruction_mode} instruction)"


@contextmanager
def blame_policy(call: str, *, policy: str | None, where: str | None) -> Iterator[None]:
    """The block calls the policy (``call``: "reset", "act", ...) and checks its output: a
    :class:`PolicyError` raised in it gets the policy and the episode named, any other exception
    becomes one (the policy raised it), keeping its traceback; so does ``sys.exit()`` (SystemExit),
    and a KeyboardInterrupt the policy raised itself where signals are guarded (a worker process:
    no Ctrl-C came). Ctrl-C passes through."""
    from rsb_maniskill.parallel.pool import from_a_signal

    try:
        yield
    except PolicyError as err:
        err.policy, err.where = err.policy or policy, err.where or where
        err.detail = err.detail or traceback.format_exc()
        raise
    except KeyboardInterrupt as err:
        if from_a_signal(err):
            raise
        raise PolicyError(f"{call} raised KeyboardInterrupt with no Ctrl-C sent: a policy must return or raise an "
                          "Exception (KeyboardInterrupt stops the whole run)", policy=policy, where=where,
                          detail=traceback.format_exc()) from err
    except SystemExit as err:  # sys.exit() in a policy must not end the evaluation as if it were done
        raise PolicyError(f"{call} called sys.exit({err.code!r}): a policy must return or raise, never exit the "
                          "process", policy=policy, where=where, detail=traceback.format_exc()) from err
    except Exception as err:
        said = one_line(str(err))
        raise PolicyError(f"{call} raised {type(err).__name__}{f': {said}' if said else ''}", policy=policy,
                          where=where, detail=traceback.format_exc()) from err


_CALL_SEP = "\x1f"  # between the call and the episode in a watched block's label


def policy_call_label(call: str, where: str) -> str:
    """How a policy call is named to the process pool's watchdog (read back by :func:`stuck_call_error`)."""
    return f"{call}{_CALL_SEP}{where}"


def stuck_call_error(label: str, policy: str, *, timeout_s: float | None = None,
                     exit_code: int | None = None) -> PolicyError:
    """The PolicyError of a policy call that outlasted its time limit (its worker was killed), or
    during which the worker process ended (``os._exit``, a crash in native code)."""
    call, _, where = label.partition(_CALL_SEP)
    if timeout_s is not None:
        message = (f"{call} did not return within {timeout_s:g} s (the limit of one policy call: "
                   "--policy-timeout SECONDS, 0 for none)")
    else:
        how = f"killed by signal {-exit_code}" if exit_code is not None and exit_code < 0 else f"exit code {exit_code}"
        message = f"{call} ended the worker process ({how}): a policy must return or raise, never exit"
    return PolicyError(message, policy=policy, where=where or None)


TRACEBACK_START = "Traceback (most recent call last):"


def one_line(text: str) -> str:
    """A message in one line. A Python traceback in it (a server's, a worker's) gives way to its cause,
    the exception line at its end, after whatever text led to it; otherwise the first line, and " ..."
    when there were more."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    if TRACEBACK_START in lines:
        lead = lines[:lines.index(TRACEBACK_START)]
        return ": ".join([*(line.rstrip(":") for line in lead), lines[-1]])
    return lines[0] + (" ..." if len(lines) > 1 else "") if lines else ""


def shown(value: Any) -> str:
    """A short description of an unexpected output: its type and the start of its repr."""
    text = repr(value)
    text = text if len(text) <= SHOWN_CHARS else text[:SHOWN_CHARS] + "..."
    return f"{type(value).__name__} {text}"
