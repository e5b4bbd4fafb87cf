"""A network that drops packets, on 127.0.0.1, and the commands that read question data with the environment
that has none: for the tests and benchmarks of what happens offline."""
from __future__ import annotations

import os
import socket
import threading
from contextlib import contextmanager
from typing import Iterator


@contextmanager
def silent_proxy_server() -> Iterator[str]:
    """A proxy's URL (``http://127.0.0.1:PORT``) that accepts connections and never answers; it
    stops when the block ends."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(64)
    held, stop = [], threading.Event()

    def accept() -> None:
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(srv.accept()[0])
            except OSError:
                continue
    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        thread.join()
        for conn in held:
            conn.close()
        srv.close()


# every command that reads GSM8K / MMLU-Pro, on a suite that needs them
COMMANDS = {
    "stats": ["stats"],
    "questions": ["questions", "RSB-HardMath-4"],
    "verify": ["verify", "RSB-General-4"],
    "eval": ["eval", "oracle", "--suites", "rsb_hardmath", "-n", "1", "--out", "{tmp}/eval"],
    "generate": ["generate", "RSB-HardMath-10", "-n", "1", "--out", "{tmp}/demos"],
    "dataset build": ["dataset", "build", "--suites", "RSB-General-10", "--out", "{tmp}/datasets"],
    "audit": ["audit", "RSB-General-4", "-n", "10"],
}


def no_data_env(tmp_path) -> dict[str, str]:
    """This process's environment without question data: an empty hub cache, no $RSB_DATA_DIR,
    no offline switch (the network is what fails)."""
    from rsb_maniskill import network  # here: conftest imports this module before any test

    env = {k: v for k, v in os.environ.items() if k not in ("RSB_DATA_DIR", *network.OFFLINE_VARS)}
    env.update(HOME=str(tmp_path), HF_HOME=str(tmp_path / "hf"), XDG_CACHE_HOME=str(tmp_path / "cache"))
    return env
