"""A hostile peer of the openpi wire protocol (``policies/remote/wire.py``, ``server.py``, ``client.py``):
every message the decoder must refuse, refused in one line on both sides, the server answering the
next well-formed client, and the size bound refusing a message before it is read. Servers bind
127.0.0.1 and stop with the test."""
from __future__ import annotations

import logging
import time

import msgpack
import numpy as np
import pytest

pytest.importorskip("websockets")

from hostile_wire import (  # noqa: E402
    HOSTILE,
    QPOS_DIM,
    StrictPolicy,
    answered,
    frame_header,
    hostile_server,
    raw_ws,
    read_close,
    request,
)
from websockets.exceptions import ConnectionClosed  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from rsb_maniskill.policies.remote.client import RemotePolicy  # noqa: E402
from rsb_maniskill.policies.remote.server import PolicyServer  # noqa: E402
from rsb_maniskill.policies.remote.wire import MIB, WireError, packb, read_request, unpackb  # noqa: E402

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def server():
    with PolicyServer(StrictPolicy(), host="127.0.0.1", port=0, max_message_mb=1) as srv:
        yield srv


def _client(port: int, **kwargs) -> RemotePolicy:
    return RemotePolicy("127.0.0.1", port, connect_timeout=10, request_timeout=20, **kwargs)


def _send_raw(port: int, message: bytes | str) -> tuple[str | None, int | None]:
    """Send one message as a client would; the server's text frame (None: it sent something else or
    nothing) and the code it closed the connection with."""
    with connect(f"ws://127.0.0.1:{port}", max_size=None, open_timeout=10) as ws:
        unpackb(ws.recv(timeout=10))  # the metadata
        ws.send(message)
        try:
            reply = ws.recv(timeout=20)
        except ConnectionClosed as err:
            return None, err.rcvd.code if err.rcvd else None
        try:
            ws.recv(timeout=20)
        except ConnectionClosed as err:
            return reply if isinstance(reply, str) else None, err.rcvd.code if err.rcvd else None
    return None, None


# ---------------------------------------------------------------- the decoder
@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_decoder_refuses_in_one_line(kind):
    with pytest.raises(WireError) as err:
        read_request(HOSTILE[kind])
    assert "\n" not in str(err.value) and len(str(err.value)) < 400


def test_decoder_takes_every_array_openpi_sends():
    """The bytes openpi's msgpack_numpy packs (its pack_array transcribed) decode to the same arrays,
    for every dtype observations and actions use, either byte order, 0-d, empty and 4-d shapes."""
    def openpi_pack_array(obj):  # openpi_client/msgpack_numpy.py
        if isinstance(obj, (np.ndarray, np.generic)) and obj.dtype.kind in ("V", "O", "c"):
            raise ValueError(f"Unsupported dtype: {obj.dtype}")
        if isinstance(obj, np.ndarray):
            return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
        if isinstance(obj, np.generic):
            return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
        return obj

    rng = np.random.default_rng(0)
    values = {}
    for code in ("?", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "f2", "f4", "f8"):
        for order in "<>":
            dtype = np.dtype(code).newbyteorder(order)
            values[f"{code}{order}"] = (rng.integers(0, 100, (2, 3, 4, 5)) % (2 if code == "?" else 100)).astype(dtype)
            values[f"{code}{order}/0d"] = np.array(1, dtype=dtype)
            values[f"{code}{order}/empty"] = np.zeros((2, 0), dtype=dtype)
            if not issubclass(dtype.type, float):  # np.float64 is a float: msgpack packs it as one
                values[f"{code}{order}/scalar"] = dtype.type(1)
    message = msgpack.packb({"obs": values, "prompt": "p", "seed": 3}, default=openpi_pack_array)
    back = unpackb(message)
    for key, value in values.items():
        got = back["obs"][key]
        assert type(got) is type(value) and got.dtype == value.dtype and np.shape(got) == np.shape(value), key
        assert np.array_equal(got, value), key
    assert packb({"obs": values, "prompt": "p", "seed": 3}) == message  # and ours packs the same bytes


def test_decoded_arrays_are_views_of_the_message_not_copies():
    a = np.arange(1000, dtype=np.float32)
    got = unpackb(packb({"a": a}))["a"]
    assert not got.flags.writeable and not got.flags.owndata  # a view over the received bytes


# ---------------------------------------------------------------- the server: one line, then the next client
@pytest.mark.parametrize("kind", sorted(HOSTILE) + ["text frame"])
def test_server_refuses_in_one_line_and_answers_the_next_client(server, kind):
    line, code = _send_raw(server.port, "hello" if kind == "text frame" else HOSTILE[kind])
    assert line is not None and line.startswith("request refused: ") and "\n" not in line, line
    assert "Traceback" not in line and ".py" not in line
    assert code == 1008
    with _client(server.port) as client:
        assert answered(client, 7)


def test_the_object_dtype_message_does_not_kill_the_server(server):
    """The 60-byte message that used to segfault `rsb serve`: refused, and every client goes on."""
    with _client(server.port) as before:
        assert answered(before, 1)
        line, _ = _send_raw(server.port, HOSTILE["object dtype"])
        assert "dtype '|O' is not allowed" in line
        assert answered(before, 2)  # a client connected all along is still served


def test_policy_error_is_one_line_with_its_cause_whole(server):
    cause = "qpos of shape (3,), expected (14,)"
    bad = request({b"__ndarray__": True, b"data": b"\x00" * 12, b"dtype": "<f4", b"shape": [3]})
    line, code = _send_raw(server.port, bad)
    assert line.startswith("policy error: ") and line.endswith(f"ValueError: {cause}") and code == 1011, line
    assert "Traceback" not in line and ".py" not in line
    with _client(server.port) as client:
        assert answered(client, 3)
        with pytest.raises(RuntimeError) as err:
            client.act({"agent": {"qpos": np.zeros(3, np.float32)}})
    # the client's one line holds the server's line whole
    assert str(err.value) == f"policy server ws://127.0.0.1:{server.port}: {line}"


class InferBroken:
    """openpi's interface (served one request at a time): fails with a chained cause."""

    def infer(self, request):
        try:
            {}["checkpoint"]
        except KeyError as err:
            raise ValueError("the model is not loaded\nsee the log") from err


@pytest.mark.parametrize("debug", [False, True])
def test_policy_traceback_in_the_server_log_with_debug_only(caplog, monkeypatch, debug):
    if debug:
        monkeypatch.setenv("RSB_DEBUG", "1")
    else:
        monkeypatch.delenv("RSB_DEBUG", raising=False)
    with PolicyServer(InferBroken(), host="127.0.0.1", port=0) as srv:
        with caplog.at_level(logging.INFO, logger="rsb_maniskill.policies.remote.server"):
            line, code = _send_raw(srv.port, request())
        with _client(srv.port) as client:  # still serving: the next client is answered (with the same error)
            with pytest.raises(RuntimeError, match="the model is not loaded"):
                client.infer({"prompt": "p"})
    assert line == ("policy error: ValueError: the model is not loaded see the log "
                    "(caused by KeyError: 'checkpoint')") and code == 1011
    records = [r for r in caplog.records if "the model is not loaded" in r.getMessage()]
    assert records and bool(records[0].exc_info) is debug  # the traceback in the server's log with --debug only


# ---------------------------------------------------------------- the size bound
def test_a_message_over_the_bound_is_refused_before_it_is_read(server):
    """A frame header announcing 1 TiB, and no payload: the server closes with 1009 at once
    (it neither waits for the bytes nor allocates them) and serves the next client."""
    sock = raw_ws(server.port)
    try:
        t0 = time.monotonic()
        sock.sendall(frame_header(1 << 40))
        code, reason = read_close(sock)
        assert code == 1009 and "exceeds limit" in reason and time.monotonic() - t0 < 5
    finally:
        sock.close()
    with _client(server.port) as client:
        assert answered(client, 4)


def test_client_names_the_bound_when_the_server_refuses_its_request(server):
    with _client(server.port) as client:
        client.reset("pick the answer", {})
        with pytest.raises(RuntimeError) as err:  # 2 MiB of qpos against the server's 1 MiB
            client.act({"agent": {"qpos": np.zeros(MIB // 2, np.float32)}})
    line = str(err.value)
    assert "\n" not in line and "refused a request of 2.0 MB as too big" in line and "--max-message-mb" in line
    with _client(server.port) as client:
        assert answered(client, 5)


def test_client_bound_on_replies():
    big = packb({"actions": np.zeros((3, MIB // 4), np.float32)})  # 3 MiB
    with hostile_server(big) as port:
        with _client(port, max_message_mb=2) as client:
            client.reset("p", {})
            with pytest.raises(RuntimeError, match=r"over this client's limit of 2 MB .*-a max_message_mb=MB"):
                client.act({"agent": {"qpos": np.zeros(QPOS_DIM, np.float32)}})
        with _client(port, max_message_mb=8) as client:  # raised: taken
            client.reset("p", {})
            assert client.act({"agent": {"qpos": np.zeros(QPOS_DIM, np.float32)}}).shape == (3, MIB // 4)


def test_bad_size_bound_is_one_line():
    with pytest.raises(ValueError, match="max_message_mb must be a number of MB > 0"):
        PolicyServer(StrictPolicy(), host="127.0.0.1", port=0, max_message_mb=0)
    with pytest.raises(ValueError, match="max_message_mb must be a number of MB > 0"):
        RemotePolicy("127.0.0.1", 1, max_message_mb=float("nan"), connect_timeout=1)


# ---------------------------------------------------------------- the client: a hostile server's replies
@pytest.mark.parametrize("kind", sorted(k for k in HOSTILE if "prompt" not in k))  # a reply has no prompt
def test_client_refuses_a_hostile_reply_in_one_line(kind):
    with hostile_server(HOSTILE[kind]) as port:
        with _client(port) as client:
            client.reset("p", {})
            with pytest.raises(RuntimeError) as err:
                client.act({"agent": {"qpos": np.zeros(QPOS_DIM, np.float32)}})
    line = str(err.value)
    assert line.startswith(f"policy server ws://127.0.0.1:{port} sent a reply this client refuses: ")
    assert "\n" not in line


def test_client_refuses_hostile_metadata_in_one_line():
    with hostile_server(b"", metadata=HOSTILE["object dtype"]) as port:
        with pytest.raises(ConnectionError, match=r"sent a metadata this client refuses: .*'\|O' is not allowed"):
            _client(port)


def test_client_shows_an_openpi_traceback_as_its_last_line():
    traceback_text = ("Traceback (most recent call last):\n  File \"/srv/openpi/serving.py\", line 60, in _handler\n"
                      "    action = self._policy.infer(obs)\nKeyError: 'observation/state'\n")
    with hostile_server(traceback_text) as port:
        with _client(port) as client:
            client.reset("p", {})
            with pytest.raises(RuntimeError) as err:
                client.act({"agent": {"qpos": np.zeros(QPOS_DIM, np.float32)}})
    assert str(err.value) == f"policy server ws://127.0.0.1:{port}: KeyError: 'observation/state'"
    assert err.value.detail == traceback_text  # rsb --debug prints it
