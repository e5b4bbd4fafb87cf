"""Plugins: installed distributions that add suites, candidate families, policies or wire protocols.

A plugin declares an entry point in the group ``rsb_maniskill.plugins`` naming a module; importing
that module registers what it adds (``register_suite``, ``register_family``, ``register_policy``,
``register_protocol``). The modules are imported once, when the suites are first read (before env ids
exist), so a plugin's suites and families get env ids, gym registrations and commands like the
built-in ones. As LeRobot's ``lerobot_env_*`` plugins: installing the distribution is the switch.

A plugin must not take the pack down: one that fails to import (an exception, ``sys.exit``, a
``KeyboardInterrupt`` it raises itself, which a Ctrl-C during its import is told apart from) or does
not finish importing within ``RSB_PLUGIN_TIMEOUT`` seconds is named on stderr in one line, with how
to turn it off (``RSB_NO_PLUGINS``), and skipped; nothing else is. A built-in name it registers is
refused (the registries raise). Worker processes inherit what the parent skipped and said: a plugin
skipped there is skipped in them without a second wait or a second line.
"""
from __future__ import annotations

import importlib
import os
import signal
import sys
import threading

GROUP = "rsb_maniskill.plugins"
DISABLE_ENV = "RSB_NO_PLUGINS"  # "1" / "all": no plugin; else the names of those to skip, comma-separated
TIMEOUT_ENV = "RSB_PLUGIN_TIMEOUT"  # seconds a plugin's import may take (default below)
DEFAULT_TIMEOUT_S = 60.0  # a plugin importing torch on a loaded machine takes seconds, not a minute
_SKIPPED_ENV = "_RSB_PLUGINS_SKIPPED"  # set for worker processes: the plugins this run skipped, already named
_loaded: list[str] | None = None


def _names(value: str | None) -> set[str]:
    return {n.strip() for n in (value or "").split(",") if n.strip()}


def _timeout_s() -> float:
    try:
        return max(0.1, float(os.environ.get(TIMEOUT_ENV, DEFAULT_TIMEOUT_S)))
    except ValueError:
        return DEFAULT_TIMEOUT_S


class _ImportTimeout(BaseException):
    """Raised into a plugin's import by the alarm (a BaseException: the plugin's ``except Exception``
    does not swallow it)."""


def _import(module: str, timeout_s: float) -> str | None:
    """Imports ``module``; why it failed (one phrase), or None. In the main thread an alarm cuts an
    import that blocks (a network call, a sleep, a lock) after ``timeout_s``: it costs that, not the
    command. (The import runs here, not in a thread: the plugin imports the module that is loading it.)"""
    timer = threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
    ctrl_c: list[int] = []  # a real Ctrl-C during the import, as opposed to a KeyboardInterrupt the plugin raised
    if timer:
        def expire(signum: int, frame: object) -> None:
            raise _ImportTimeout

        previous = signal.signal(signal.SIGALRM, expire)
        signal.setitimer(signal.ITIMER_REAL, timeout_s)
        on_int = signal.getsignal(signal.SIGINT)

        def note(signum: int, frame: object) -> None:
            ctrl_c.append(signum)
            if callable(on_int):  # the command's start-up guard (it exits), or Python's KeyboardInterrupt
                on_int(signum, frame)
            elif on_int != signal.SIG_IGN:
                raise KeyboardInterrupt

        signal.signal(signal.SIGINT, note)
    try:
        importlib.import_module(module)
        return None
    except _ImportTimeout:
        return f"its import did not finish within {timeout_s:g} s ({TIMEOUT_ENV} sets the limit)"
    except SystemExit as stop:  # sys.exit at import: it would end every command without a word
        return f"it called sys.exit({stop.code!r}) while importing"
    except KeyboardInterrupt:
        if ctrl_c or not timer:  # Ctrl-C (or no way to tell it from one): the user's, not the plugin's
            raise
        return "it raised KeyboardInterrupt while importing (no Ctrl-C was pressed)"
    except BaseException as err:  # noqa: BLE001  (a broken plugin is named, not raised)
        return f"{type(err).__name__}: {err}"
    finally:
        if timer:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
            if on_int is not None:  # (None: a handler not set from Python, left as it was)
                signal.signal(signal.SIGINT, on_int)


def skip_plugins() -> None:
    """This process loads no plugin (``rsb --version`` / ``--help``); call it before the suites are read."""
    global _loaded
    if _loaded is None:
        _loaded = []


def load_plugins() -> list[str]:
    """Import every plugin module once; the names of those that loaded (in entry-point order)."""
    global _loaded
    if _loaded is not None:
        return _loaded
    _loaded = []
    disabled = _names(os.environ.get(DISABLE_ENV))
    if disabled & {"1", "all", "true", "yes"}:
        return _loaded
    from importlib.metadata import entry_points

    said = _names(os.environ.get(_SKIPPED_ENV))  # named by the parent process already
    skipped = set(said)
    for ep in entry_points(group=GROUP):
        if ep.name in disabled or ep.name in said:
            continue
        why = _import(ep.value.partition(":")[0], _timeout_s())
        if why is not None:
            skipped.add(ep.name)
            print(f"rsb_maniskill: plugin {ep.name!r} ({ep.value}) failed to load and is skipped: {why} "
                  f"(without it: {DISABLE_ENV}={ep.name})", file=sys.stderr)
            continue
        _loaded.append(ep.name)
    if skipped:
        os.environ[_SKIPPED_ENV] = ",".join(sorted(skipped))
    return _loaded
