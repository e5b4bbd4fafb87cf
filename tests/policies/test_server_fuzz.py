"""Fuzzing `rsb serve` on 127.0.0.1: every hostile kind of message (``hostile_wire.HOSTILE``, a text
frame, one over the size bound), then mutated and random ones, each on its own connection, against a
server in its own process. After each, a well-formed client connected all along is answered; the
server never dies and its memory does not grow. Bounded by a count and a time budget; the server
stops with the test."""
from __future__ import annotations

import time

import msgpack
import numpy as np
import pytest

pytest.importorskip("websockets")

from hostile_wire import HOSTILE, answered, frame_header, raw_ws, read_close, rss_mb, served  # noqa: E402
from websockets.exceptions import ConnectionClosed  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from rsb_maniskill.policies.remote.client import RemotePolicy  # noqa: E402
from rsb_maniskill.policies.remote.wire import packb  # noqa: E402

pytestmark = pytest.mark.timeout(110)

MAX_MESSAGES = 600  # mutated / random messages at most, after the named kinds
BUDGET_S = 25.0  # and at most this long (a loaded CI machine runs fewer)
MIN_RANDOM = 50  # fewer than this in the budget: the server is too slow, and that is a failure
RSS_GROWTH_MB = 16.0  # from after the named kinds and the warm-up to the end
SIZE_MB = 1  # the server's --max-message-mb: an oversize message is cheap to announce

GOOD_DTYPES = ["|b1", "|u1", "<i4", "<i8", "<f4", ">f8", "<f2"]
BAD_DTYPES = ["|O", "|V8", "<U4", "<c8", "|S3", "O", "float32", "<f16", "(2,)<f4", "", "|O8", b"<f4"]


def _well_formed(rng: np.random.Generator) -> bytes:
    """A request as RemotePolicy sends one: single-env, or batched with env ids and seeds."""
    rows = int(rng.integers(0, 3))
    qpos = rng.standard_normal((rows, 14) if rows else 14).astype(np.float32)
    rgb = rng.integers(0, 256, ((rows,) if rows else ()) + (8, 8, 3), dtype=np.uint8)
    request = {"observation/agent/qpos": qpos, "observation/sensor_data/head_camera/rgb": rgb,
               "prompt": ["p"] * rows if rows else "pick the answer", "episode_start": bool(rng.integers(0, 2))}
    if rows:
        request["env_ids"] = np.arange(rows, dtype=np.int64)
        request["episode_seeds"] = np.arange(rows, dtype=np.int64)
    return packb(request)


def _mutated(rng: np.random.Generator) -> bytes:
    data = bytearray(_well_formed(rng))
    how = int(rng.integers(0, 4))
    if how == 0:  # flip bytes
        for i in rng.integers(0, len(data), int(rng.integers(1, 8))):
            data[i] = int(rng.integers(0, 256))
    elif how == 1:  # cut
        del data[int(rng.integers(0, len(data))):]
    elif how == 2:  # insert
        at = int(rng.integers(0, len(data)))
        data[at:at] = rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
    else:  # repeat a slice
        a = int(rng.integers(0, len(data)))
        data[a:a] = data[a:a + int(rng.integers(1, 256))] * int(rng.integers(1, 4))
    return bytes(data)


def _random_tag(rng: np.random.Generator) -> dict:
    dtype = str(rng.choice(GOOD_DTYPES + BAD_DTYPES))
    ndim = int(rng.integers(0, 5)) if rng.random() < 0.95 else int(rng.integers(33, 80))
    shape = [int(d) for d in rng.integers(-3, 6, ndim)]
    if rng.random() < 0.1:
        shape = [2**62, 2**62] if rng.random() < 0.5 else [2**64 - 1, 0]
    size = int(np.prod(np.maximum(shape, 0), dtype=object)) if shape else 1
    itemsize = 8 if dtype in BAD_DTYPES else np.dtype(dtype).itemsize
    n = size * itemsize + int(rng.choice([0, 0, 0, -1, 1, 1000]))
    return {b"__ndarray__": True, b"data": b"\x00" * max(0, min(n, 1 << 16)), b"dtype": dtype, b"shape": shape}


def _random_value(rng: np.random.Generator, depth: int = 0):
    kind = int(rng.integers(0, 9 if depth < 6 else 6))
    if kind == 0:
        return _random_tag(rng)
    if kind == 1:
        return {b"__npgeneric__": True, b"data": rng.choice([1000, -1, 2.5, True, "x"]).item(),
                b"dtype": str(rng.choice(GOOD_DTYPES + BAD_DTYPES))}
    if kind == 2:
        return rng.bytes(int(rng.integers(0, 32)))
    if kind == 3:
        return int(rng.integers(-(2**62), 2**62))
    if kind == 4:
        return "x" * int(rng.integers(0, 40))
    if kind == 5:
        return None
    if kind in (6, 7):
        return {f"k{i}": _random_value(rng, depth + 1) for i in range(int(rng.integers(0, 4)))}
    return [_random_value(rng, depth + 1) for _ in range(int(rng.integers(0, 4)))]


def _random(rng: np.random.Generator) -> bytes:
    how = int(rng.integers(0, 3))
    if how == 0:
        return rng.bytes(int(rng.integers(0, 512)))
    if how == 1:
        body = {f"observation/k{i}": _random_value(rng) for i in range(int(rng.integers(0, 4)))}
        body["prompt"] = _random_value(rng) if rng.random() < 0.5 else "p"
        return msgpack.packb(body)
    return msgpack.packb(_random_value(rng))


def _send(port: int, message: bytes | str, timeout: float = 10.0) -> None:
    """One hostile message on its own connection; whatever comes back is one line or an answer."""
    with connect(f"ws://127.0.0.1:{port}", max_size=None, open_timeout=10, close_timeout=2) as ws:
        ws.recv(timeout=10)  # the metadata
        ws.send(message)
        try:
            reply = ws.recv(timeout=timeout)
        except ConnectionClosed:
            return
        assert not isinstance(reply, str) or "\n" not in reply, reply


def test_fuzz_the_server(tmp_path):
    t_start = time.monotonic()
    rng = np.random.default_rng(67)
    with served(tmp_path, "--max-message-mb", str(SIZE_MB)) as (port, proc, log):
        with RemotePolicy("127.0.0.1", port, connect_timeout=10, request_timeout=60) as good:
            step = 0

            def still_served(what: str) -> None:
                nonlocal step
                step += 1
                assert proc.poll() is None, f"the server died after {what}: {log.read_text()[-2000:]}"
                assert answered(good, step), f"the well-formed client was not answered after {what}"

            for kind, message in HOSTILE.items():
                _send(port, message)
                still_served(kind)
            _send(port, "a text frame")
            still_served("a text frame")
            for _ in range(3):
                sock = raw_ws(port)
                try:
                    sock.sendall(frame_header(SIZE_MB * (1 << 20) + 1 if _ else 1 << 40))
                    assert read_close(sock)[0] == 1009
                finally:
                    sock.close()
                still_served("a message over the bound")
            for _ in range(3):  # the first row copy imports torch (220 MB; > 10 s on a loaded machine)
                _send(port, _well_formed(rng), timeout=60)
                still_served("a well-formed message")
            rss = [rss_mb(proc.pid)]
            t0, sent = time.monotonic(), 0
            while sent < MAX_MESSAGES and time.monotonic() - t0 < BUDGET_S:
                make = (_mutated, _random)[sent % 2]
                message = make(rng)
                _send(port, message)
                still_served(f"{make.__name__} message {sent}: {message[:80]!r}")
                sent += 1
                if sent % 50 == 0:
                    rss.append(rss_mb(proc.pid))
            rss.append(rss_mb(proc.pid))
    print(f"fuzz: {len(HOSTILE) + 7} named and well-formed + {sent} random messages in {time.monotonic() - t0:.1f} s "
          f"({time.monotonic() - t_start:.1f} s with the server's start); server RSS {rss[0]:.0f} -> "
          f"max {max(rss):.0f} -> {rss[-1]:.0f} MB")
    assert sent >= MIN_RANDOM
    assert max(rss) - rss[0] < RSS_GROWTH_MB, rss
    assert "Traceback" not in log.read_text()  # without --debug the server's log holds lines, not tracebacks
