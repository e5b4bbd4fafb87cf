"""Who may talk to `rsb serve`: 127.0.0.1 unless --host says otherwise (said at start), an optional
token clients must send (``--token`` / ``$RSB_SERVE_TOKEN``, ``-a token=`` on the client side), and
what a client says while no server is there. Servers bind 127.0.0.1 and stop with the test."""
from __future__ import annotations

import socket
import time
import urllib.request

import pytest

pytest.importorskip("websockets")

from hostile_wire import StrictPolicy, answered, served  # noqa: E402

from rsb_maniskill.policies.remote.client import RemotePolicy, check_remote_args  # noqa: E402
from rsb_maniskill.policies.remote.server import PolicyServer, _exposure  # noqa: E402
from rsb_maniskill.policies.remote.wire import TOKEN_ENV  # noqa: E402

pytestmark = pytest.mark.timeout(120)
TOKEN = "s3cret-t0ken"


@pytest.fixture(scope="module")
def guarded():
    with PolicyServer(StrictPolicy(), host="127.0.0.1", port=0, token=TOKEN) as srv:
        yield srv


def _client(port: int, **kwargs) -> RemotePolicy:
    return RemotePolicy("127.0.0.1", port, connect_timeout=5, request_timeout=20, **kwargs)


def test_rsb_serve_listens_on_this_machine_by_default(capsys):
    from rsb_maniskill.cli import main

    assert main(["serve", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "--host HOST interface to listen on (default 127.0.0.1: this machine only" in out
    assert "--token" in out and TOKEN_ENV in out and "--max-message-mb" in out


def test_the_start_says_who_can_reach_it():
    assert "this machine only" in _exposure("127.0.0.1", 8000, None)
    assert "this machine only" in _exposure("::1", 8000, TOKEN)
    warning = _exposure("0.0.0.0", 8000, None)
    assert warning.startswith("rsb serve: warning:") and "no token" in warning and "--token" in warning
    assert "clients must send the token" in _exposure("0.0.0.0", 8000, TOKEN)


def test_a_client_without_the_token_is_refused_in_one_line(guarded, monkeypatch):
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    with pytest.raises(ConnectionError) as err:
        _client(guarded.port)
    line = str(err.value)
    assert line.startswith(f"policy server ws://127.0.0.1:{guarded.port} refused the connection: HTTP 401")
    assert "needs a token: -a token=... or $RSB_SERVE_TOKEN" in line and "\n" not in line
    with pytest.raises(ConnectionError, match=r"HTTP 403 Forbidden: wrong token for this policy server$"):
        _client(guarded.port, token="not-" + TOKEN)


def test_a_client_with_the_token_is_served(guarded, monkeypatch):
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    with _client(guarded.port, token=TOKEN) as client:
        assert answered(client, 1)
    monkeypatch.setenv(TOKEN_ENV, TOKEN)  # the remote policy reads it as rsb serve does
    with _client(guarded.port) as client:
        assert answered(client, 2)


def test_health_check_needs_no_token(guarded):
    with urllib.request.urlopen(f"http://127.0.0.1:{guarded.port}/healthz", timeout=10) as reply:
        assert reply.status == 200


def test_rsb_serve_takes_its_token_from_the_environment(tmp_path, monkeypatch):
    import os

    env = dict(os.environ, **{TOKEN_ENV: TOKEN})
    with served(tmp_path, env=env) as (port, _proc, log):
        monkeypatch.delenv(TOKEN_ENV, raising=False)
        with pytest.raises(ConnectionError, match="HTTP 401"):
            _client(port)
        with _client(port, token=TOKEN) as client:
            assert answered(client, 3)
        assert "rsb serve: 127.0.0.1 is this machine only" in log.read_text()


def test_no_server_says_where_it_connects_and_ends_in_one_line(capsys):
    with socket.socket() as s:  # a port with nobody listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    with pytest.raises(ConnectionError) as err:
        check_remote_args({"host": "127.0.0.1", "port": port, "connect_timeout": 1}, "state")
    assert time.monotonic() - t0 < 10
    assert f"waiting up to 1 s for a policy server at ws://127.0.0.1:{port}" in capsys.readouterr().err
    line = str(err.value)
    assert line.startswith(f"no policy server at ws://127.0.0.1:{port} after 1 s") and "\n" not in line
    assert "-a connect_timeout=S" in line


def test_check_remote_args_refused_handshake_has_no_misleading_hint(guarded, monkeypatch):
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    with pytest.raises(ConnectionError) as err:
        check_remote_args({"host": "127.0.0.1", "port": guarded.port, "connect_timeout": 5}, "state")
    assert "HTTP 401" in str(err.value) and "start the policy server" not in str(err.value)
