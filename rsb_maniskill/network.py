"""When the package may use the network, and a probe that answers within seconds.

Two things need the network, and only when a file is missing: the pinned GSM8K / MMLU-Pro hub
files (``semantic/data.py``) and SAPIEN's PhysX GPU library (``sim/physx_gpu.py``). On a machine
without network neither may wait: ``RSB_OFFLINE=1`` (or ``HF_HUB_OFFLINE=1``) rules the network
out, and otherwise :func:`unreachable` asks the host once per process, with one deadline for the
name lookup, the connection and the answer, before a client with its own retries is let loose
(huggingface_hub's took three minutes to give up on a machine without network).
"""
from __future__ import annotations

import os
import threading

OFFLINE_VARS = ("RSB_OFFLINE", "HF_HUB_OFFLINE")  # either set to 1: never touch the network
PROBE_TIMEOUT = 3.0  # s: a host that has not answered by then is unreachable

_PROBED: dict[str, str | None] = {}  # url -> None (it answered) or why not, once per process


def offline() -> bool:
    """True when an offline switch is set."""
    return any(os.environ.get(v, "").strip().lower() in ("1", "true", "yes") for v in OFFLINE_VARS)


def unreachable(url: str, timeout: float = PROBE_TIMEOUT) -> str | None:
    """None when ``url``'s host answers an HTTP HEAD within ``timeout`` seconds (any status: the
    host is there), else a few words saying why not. Proxies from the environment apply, as for
    the clients. The request runs in a daemon thread, so a name lookup that hangs (no DNS server
    reachable) counts against the same deadline; the verdict is kept for the rest of the process."""
    if offline():
        return f"offline ({' or '.join(OFFLINE_VARS)} is set)"
    if url not in _PROBED:
        verdict: list[str | None] = [f"no answer from {url} within {timeout:g} s"]

        def probe() -> None:
            import requests

            try:
                requests.head(url, timeout=timeout, allow_redirects=False)
                verdict[0] = None
            except requests.RequestException as err:
                verdict[0] = f"{url} unreachable ({type(err).__name__})"

        thread = threading.Thread(target=probe, daemon=True, name="rsb-network-probe")
        thread.start()
        thread.join(timeout + 0.2)
        _PROBED[url] = verdict[0]
    return _PROBED[url]
