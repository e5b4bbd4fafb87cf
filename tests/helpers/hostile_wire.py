"""Messages a hostile peer of the openpi wire protocol sends, a policy that checks what it gets, a
`rsb serve` process to send them to and a server that answers with them (127.0.0.1, stopping by
themselves): for the tests of ``policies/remote/wire.py``'s decoder and the server's error path."""
from __future__ import annotations

import os
import re
import socket
import struct
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import msgpack
import numpy as np

HELPERS = Path(__file__).resolve().parent
QPOS_DIM, HORIZON = 14, 3


def _tag(dtype: str, shape: list, data: bytes) -> dict:
    return {b"__ndarray__": True, b"data": data, b"dtype": dtype, b"shape": shape}


def request(tag: dict | None = None, prompt: object = "pick the answer") -> bytes:
    """A request as RemotePolicy sends one; ``tag`` (a raw array tag) in place of its qpos."""
    qpos = tag if tag is not None else _tag("<f4", [QPOS_DIM], np.arange(QPOS_DIM, dtype=np.float32).tobytes())
    return msgpack.packb({"observation/agent/qpos": qpos, "prompt": prompt})


def nested(levels: int) -> bytes:
    """``levels`` maps, one inside the other: ``{"a": {"a": ... nil}}``."""
    return b"\x81\xa1a" * levels + b"\xc0"


# Every kind of hostile message the issue lists (a text frame and one over the size bound aside):
# what each is, as bytes. The object dtype one is the 60-byte message that used to kill the server.
HOSTILE: dict[str, bytes] = {
    "object dtype": request(_tag("|O", [1], b"\x10\x00\x00\x00\x00\x00\x00\x00")),
    "void dtype": request(_tag("|V8", [1], b"\x00" * 8)),
    "structured dtype": request(_tag("[('a', '<f4')]", [1], b"\x00" * 4)),
    "unicode dtype": request(_tag("<U1", [1], b"\x00" * 4)),
    "negative shape": request(_tag("<f4", [-1], b"")),
    "shape larger than its data": request(_tag("<f4", [10**6], b"\x00" * 8)),
    "shape of 2**62 zeros": request(_tag("<f4", [2**62, 0], b"")),
    "dim over int64": request(_tag("<f4", [2**64 - 1, 0], b"")),
    "too many dims": request(_tag("|u1", [1] * 100, b"\x00")),
    "bool in shape": request(_tag("<f4", [True], b"\x00" * 4)),
    "data not bytes": request(_tag("<f4", [1], "abcd")),
    "scalar out of range": msgpack.packb({"x": {b"__npgeneric__": True, b"data": 1000, b"dtype": "|i1"}}),
    "not msgpack": b"\xc1\xc1\xc1\xc1",
    "truncated msgpack": request()[:-5],
    "trailing bytes": request() + b"\x00",
    "a list instead of a dict": msgpack.packb([1, 2, 3]),
    "a number": msgpack.packb(7),
    "a number as prompt": request(prompt=5),
    "a list of numbers as prompt": request(prompt=[1, 2]),
    "100,000 levels of nesting": nested(100_000),
    "100,000 levels of lists": b"\x91" * 100_000 + b"\xc0",
    "40 levels of nesting": nested(40),
    "extension type": msgpack.packb({"x": msgpack.ExtType(5, b"abc")}),
    "timestamp": msgpack.packb({"x": msgpack.Timestamp(1)}),
    "not utf-8": b"\x81\xa2\xff\xfe\xc0",
    "list as map key": b"\x81\x91\x01\x01",
}


class StrictPolicy:
    """A single-env policy that checks its observation: the chunk is its qpos, HORIZON times."""

    def reset(self, instruction: str, obs: dict) -> None:
        pass

    def act(self, obs: dict) -> np.ndarray:
        qpos = np.asarray(obs["agent"]["qpos"], dtype=np.float32)
        if qpos.shape != (QPOS_DIM,):
            raise ValueError(f"qpos of shape {qpos.shape}, expected ({QPOS_DIM},)")
        return np.tile(qpos, (HORIZON, 1))


def make_policy() -> StrictPolicy:
    return StrictPolicy()


def answered(client, step: int) -> bool:
    """A well-formed request of ``client`` (a RemotePolicy) gets its own answer."""
    qpos = np.full(QPOS_DIM, step, dtype=np.float32)
    client.reset("pick the answer", {})
    chunk = client.act({"agent": {"qpos": qpos}})
    return chunk.shape == (HORIZON, QPOS_DIM) and bool(np.all(chunk == step))


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid``, or of its one child when it is `timeout` (Linux /proc)."""
    if Path(f"/proc/{pid}/comm").read_text().strip() == "timeout":
        pid = int(Path(f"/proc/{pid}/task/{pid}/children").read_text().split()[0])
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for {pid}")


@contextmanager
def served(tmp_path: Path, *args: str, env: dict | None = None) -> Iterator[tuple[int, subprocess.Popen, Path]]:
    """`python -m rsb_maniskill.policies.remote.server hostile_wire:make_policy --host 127.0.0.1 --port 0 ARGS`
    in its own process (killed after 120 s whatever happens): its port, the process and its stderr log."""
    log = tmp_path / "server.log"
    env = dict(os.environ if env is None else env, PYTHONPATH=os.pathsep.join([str(HELPERS), *sys.path]))
    with open(log, "w") as err:
        proc = subprocess.Popen(["timeout", "120", sys.executable, "-m", "rsb_maniskill.policies.remote.server",
                                 "hostile_wire:make_policy", "--host", "127.0.0.1", "--port", "0", *args],
                                stdout=err, stderr=subprocess.STDOUT, env=env)
    try:
        deadline, port = time.monotonic() + 60, None
        while port is None and time.monotonic() < deadline and proc.poll() is None:
            m = re.search(r"listening on ws://127\.0\.0\.1:(\d+)", log.read_text())
            port = int(m.group(1)) if m else time.sleep(0.1)
        assert port, f"server did not start: {log.read_text()}"
        yield port, proc, log
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def hostile_server(reply: bytes | str, metadata: bytes | None = None) -> Iterator[int]:
    """A websocket server on 127.0.0.1 that sends ``metadata`` (default: a well-formed dict), then
    answers every message with ``reply``; its port."""
    from websockets.sync.server import serve

    def handler(ws) -> None:
        try:
            ws.send(metadata if metadata is not None else msgpack.packb({}))
            while True:
                ws.recv()
                ws.send(reply)
        except Exception:  # noqa: BLE001  (the client left)
            pass

    server = serve(handler, "127.0.0.1", 0, compression=None, max_size=None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield int(server.socket.getsockname()[1])
    finally:
        server.shutdown()
        thread.join(timeout=10)


def raw_ws(port: int, headers: str = "") -> socket.socket:
    """A websocket handshake by hand, so a test can send any frame header."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
                  f"{headers}\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = sock.recv(4096)
        assert chunk, f"server closed during the handshake: {head!r}"
        head += chunk
    assert head.startswith(b"HTTP/1.1 101"), head
    return sock


def frame_header(length: int, opcode: int = 2) -> bytes:
    """A masked client frame's header announcing ``length`` bytes of payload (none follow)."""
    return bytes([0x80 | opcode, 0x80 | 127]) + struct.pack("!Q", length) + b"\x00\x00\x00\x00"


def read_close(sock: socket.socket, timeout: float = 10.0) -> tuple[int, str]:
    """The code and reason of the server's close frame (skipping the metadata frame before it)."""
    sock.settimeout(timeout)
    buf = b""
    while True:
        while len(buf) < 2:
            buf += _recv(sock)
        opcode, n = buf[0] & 0x0F, buf[1] & 0x7F
        head = 2
        if n == 126:
            while len(buf) < 4:
                buf += _recv(sock)
            n, head = struct.unpack("!H", buf[2:4])[0], 4
        elif n == 127:
            while len(buf) < 10:
                buf += _recv(sock)
            n, head = struct.unpack("!Q", buf[2:10])[0], 10
        while len(buf) < head + n:
            buf += _recv(sock)
        payload, buf = buf[head:head + n], buf[head + n:]
        if opcode == 8:
            return struct.unpack("!H", payload[:2])[0], payload[2:].decode()


def _recv(sock: socket.socket) -> bytes:
    chunk = sock.recv(65536)
    if not chunk:
        raise ConnectionError("closed without a close frame")
    return chunk
