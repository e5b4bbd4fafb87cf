"""An openpi-compatible websocket policy server that batches: one model for every client.

Serves an RSB :class:`~rsb_maniskill.policies.interface.Policy` (``reset``/``act``, and the batched
form ``reset_batch``/``act_batch``), an openpi-style object (``infer(obs: dict) -> dict`` with
``"actions"``) or a backbone (``answer``). Same wire protocol as openpi's ``WebsocketPolicyServer``
(see ``wire.py``), so openpi's client, :class:`RemotePolicy` and the vla-eval adapter talk to it.

An RSB policy is served by a :class:`~rsb_maniskill.policies.remote.batching.Batcher`: the
requests of every connection are gathered for at most ``max_wait_ms`` or ``max_batch`` rows (envs)
and answered by one ``act_batch`` over all their rows (a single-env policy: one row at a time,
each row its own copy); a policy call past ``policy_timeout`` fails its rows. ``infer`` and
``answer`` objects are served one request at a time.

Run one from the shell: ``rsb serve pkg.mod:make_policy --port 8000`` (or
``python -m rsb_maniskill.policies.remote.server pkg.mod:make_policy --port 8000``).
"""
from __future__ import annotations

import argparse
import errno
import hmac
import http
import ipaddress
import logging
import math
import os
import signal
import sys
import threading
import time
from typing import Any, Callable

import numpy as np

from rsb_maniskill.debug import debug_enabled
from rsb_maniskill.policies.errors import POLICY_TIMEOUT_S
from rsb_maniskill.policies.interface import is_batched
from rsb_maniskill.policies.registry import load_policy, policy_spec
from rsb_maniskill.policies.remote.batching import (
    DEFAULT_MAX_BATCH,
    DEFAULT_MAX_WAIT_MS,
    MAX_BATCH_LIMIT,
    MAX_WAIT_LIMIT_MS,
    Batcher,
    Request,
    ServedPolicyError,
)
from rsb_maniskill.policies.remote.openpi import PRESETS, make_preset
from rsb_maniskill.policies.remote.wire import (
    DEFAULT_MAX_MESSAGE_MB,
    INSTALL_HINT,
    TOKEN_ENV,
    TOKEN_SCHEME,
    WireError,
    max_message_bytes,
    packb,
    read_request,
    unflatten_obs,
)
from rsb_maniskill.resolve import key_values

logger = logging.getLogger(__name__)
READY = "rsb serve: listening on"  # the line a parent process reads the port from (stdout)
PARENT_POLL_S = 1.0  # --parent-pid: how often the server checks that its parent still lives
STOP_CLOSE_S = 3.0  # how long a stopping server waits for its connections to close (Ctrl-C: out within 5 s)


def _request_obs(request: dict, prefix: str) -> Any:
    """The observation of a request: a flat "state" observation (one array under the prefix) as the
    array itself, as the policy gets it in-process; else the nested dict of its keys."""
    if prefix in request:
        return request[prefix]
    return unflatten_obs(request, prefix)


class BackboneAdapter:
    """openpi ``infer`` on top of a backbone (``answer(instruction, images) -> str``): the request's
    ``prompt`` and ``images`` in, ``{"text": answer}`` out (``client.RemoteBackbone``'s protocol)."""

    def __init__(self, backbone: Any, prompt_key: str = "prompt") -> None:
        self.backbone = backbone
        self.prompt_key = prompt_key

    def infer(self, request: dict) -> dict:
        images = request.get("images") or {}
        return {"text": str(self.backbone.answer(str(request.get(self.prompt_key, "")), dict(images)))}


def _gatekeeper(token: str | None) -> Any:
    """The handshake's check (websockets' ``process_request``): ``GET /healthz`` -> 200, as openpi's
    server does; with a token, a client without ``Authorization: Api-Key TOKEN`` gets 401 (none sent)
    or 403 (another), with a one-line reason, before any message is read."""
    expected = f"{TOKEN_SCHEME} {token}".encode() if token else None

    def check(connection: Any, request: Any) -> Any:
        if getattr(request, "path", None) == "/healthz":
            return connection.respond(http.HTTPStatus.OK, "OK\n")
        if expected is None:
            return None
        sent = request.headers.get("Authorization")
        if sent is None:
            return connection.respond(http.HTTPStatus.UNAUTHORIZED, "this policy server needs a token: "
                                      f"-a token=... or ${TOKEN_ENV} (header Authorization: {TOKEN_SCHEME} ...)\n")
        if not hmac.compare_digest(sent.encode("utf-8", errors="replace"), expected):  # constant time
            return connection.respond(http.HTTPStatus.FORBIDDEN, "wrong token for this policy server\n")
        return None

    return check


def _peer(ws: Any) -> str:
    try:
        address = ws.remote_address
    except (AttributeError, OSError):  # the socket is closed already
        return "a client"
    return f"{address[0]}:{address[1]}" if isinstance(address, tuple) and len(address) >= 2 else "a client"


def _one_line(err: BaseException) -> str:
    """An exception as one line, its message and its cause's whole (newlines folded)."""
    def line(e: BaseException) -> str:
        return " ".join(f"{type(e).__name__}: {e}".split()) if str(e) else type(e).__name__
    cause = err.__cause__ or (None if err.__suppress_context__ else err.__context__)
    return line(err) + (f" (caused by {line(cause)})" if cause is not None else "")


def _send_error(ws: Any, line: str, code: int) -> None:
    """As openpi's server: the error as a text frame (openpi's client raises with it), then close; here
    one line, never a traceback. 1008: the client's message was wrong; 1011: the policy failed."""
    try:
        ws.send(" ".join(line.split()))
        ws.close(code=code, reason="bad request" if code == 1008 else "policy error")
    except Exception:  # noqa: BLE001  (the client is gone already: nothing left to tell it)
        pass


def _exposure(host: str, port: int, token: str | None) -> str:
    """Who can reach the server, said once at start."""
    try:
        local = ipaddress.ip_address(host).is_loopback
    except ValueError:
        local = host == "localhost"
    if local:
        return (f"rsb serve: {host} is this machine only; other machines: an SSH tunnel to port {port}, or "
                "--host 0.0.0.0 with --token")
    if token:
        return f"rsb serve: listening on {host}, reachable from other machines; clients must send the token"
    return (f"rsb serve: warning: listening on {host} with no token: anyone who reaches port {port} can use this "
            f"policy (--token, or ${TOKEN_ENV})")


def _with_row_dim(obs: Any) -> Any:
    if isinstance(obs, dict):
        return {k: _with_row_dim(v) for k, v in obs.items()}
    return np.asarray(obs)[None]


class PolicyServer:
    """Serve ``policy`` over websocket; ``port=0`` picks a free port (read it from ``.port``).

    ``start()`` serves from a background thread (tests, notebooks); ``serve_forever()`` blocks.
    An RSB policy's requests are batched across connections (``max_batch`` rows, ``max_wait_ms``; a
    call past ``policy_timeout`` seconds fails its rows); ``.batcher.sizes`` counts the rows of each
    policy call. ``log`` gets the batcher's lines (stderr by default). A policy that cannot be
    served (a batched one without ``reset_envs``): ValueError, one line.
    """

    def __init__(
        self,
        policy: Any,
        host: str = "127.0.0.1",
        port: int = 8000,
        metadata: dict | None = None,
        prompt_key: str = "prompt",
        obs_prefix: str = "observation",
        preset: Any = None,
        max_batch: int = DEFAULT_MAX_BATCH,
        max_wait_ms: float = DEFAULT_MAX_WAIT_MS,
        policy_timeout: float | None = None,
        log: Callable[[str], None] | None = None,
        token: str | None = None,
        max_message_mb: float = DEFAULT_MAX_MESSAGE_MB,
    ) -> None:
        try:
            from websockets.sync.server import serve
        except ImportError as err:  # pragma: no cover - depends on the install
            raise ImportError(INSTALL_HINT) from err
        self.policy = policy
        self.metadata = dict(metadata or {})
        self.prompt_key = prompt_key
        self.obs_prefix = obs_prefix
        self.preset = preset
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        rsb_policy = is_batched(policy) or all(callable(getattr(policy, m, None)) for m in ("reset", "act"))
        openpi_style = preset is None and callable(getattr(policy, "infer", None))
        self.batcher = Batcher(policy, max_batch, max_wait_ms, log=log, policy_timeout=policy_timeout) \
            if rsb_policy and not openpi_style else None
        self._server = serve(
            self._handle, host, port, compression=None, max_size=max_message_bytes(max_message_mb, "max_message_mb"),
            process_request=_gatekeeper(token)
        )
        self.host = host
        self.port = int(self._server.socket.getsockname()[1])

    def describe(self) -> str:
        """How requests are answered (said once at start)."""
        if self.batcher is not None:
            return self.batcher.describe()
        return f"{type(self.policy).__name__}: one request at a time"

    def _infer_fn(self) -> Any:
        if self.preset is None and callable(getattr(self.policy, "infer", None)):
            return self.policy.infer
        return BackboneAdapter(self.policy, self.prompt_key).infer

    # ------------------------------------------------------------ batched serving
    def _request(self, conn: int, request: dict) -> tuple[Request, bool]:
        """A decoded request (its rows) and whether it was a single-env one."""
        request = dict(request)
        prompt = request.pop(self.prompt_key, "")
        start = bool(request.pop("episode_start", False))
        seeds = request.pop("episode_seeds", None)  # the episodes' seeds (RemotePolicy with mark_episode_start)
        seed = request.pop("episode_seed", None)
        if isinstance(prompt, list):
            if self.preset:
                raise TypeError("the openpi-aloha preset takes one observation per request, not a batch")
            envs = [int(e) for e in request.pop("env_ids", range(len(prompt)))]
            rows = Request(conn, envs, [str(p) for p in prompt], start, _request_obs(request, self.obs_prefix))
            rows.seeds = None if seeds is None else [int(s) for s in seeds]
            return rows, False
        obs = self.preset.obs_from_request(request) if self.preset else _request_obs(request, self.obs_prefix)
        rows = Request(conn, [0], [str(prompt)], start, _with_row_dim(obs))
        rows.seeds = None if seed is None else [int(seed)]
        return rows, True

    def respond(self, conn: int, request: dict) -> dict:
        """The reply to one decoded request of connection ``conn`` (``self.batcher.open()``): its rows
        answered with the other connections' (what a websocket connection is sent back)."""
        assert self.batcher is not None
        rows, single = self._request(conn, request)
        chunks, texts = self.batcher.submit(rows)
        if single:
            reply = {"actions": self.preset.aloha_actions(chunks[0]) if self.preset else chunks[0]}
            return reply if texts[0] is None else {**reply, "text": texts[0]}
        reply = {"actions": np.stack(chunks)}
        return reply if all(t is None for t in texts) else {**reply, "text": texts}

    def _handle(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        conn = self.batcher.open() if self.batcher is not None else -1
        infer = self._infer_fn() if self.batcher is None else None
        try:
            ws.send(packb(self.metadata))
            while True:
                request = read_request(ws.recv(), self.prompt_key)
                t0 = time.monotonic()
                if infer is None:
                    reply = self.respond(conn, request)
                else:
                    with self._lock:
                        reply = dict(infer(request))
                reply["server_timing"] = {"infer_ms": 1000.0 * (time.monotonic() - t0)}
                ws.send(packb(reply))
        except ConnectionClosed as err:
            if err.sent is not None and err.sent.code == 1009:  # over --max-message-mb: refused before it was read
                logger.warning("rsb serve: refused a message from %s: %s (--max-message-mb raises the limit)",
                               _peer(ws), err.sent.reason)
            return
        except WireError as err:  # the client's message: what is wrong with it, to that client only
            logger.warning("rsb serve: refused a request from %s: %s", _peer(ws), err)
            _send_error(ws, f"request refused: {err}", 1008)
        except BaseException as err:  # noqa: BLE001  (the policy's; in a handler thread even KeyboardInterrupt is)
            if isinstance(err, ServedPolicyError):  # the batcher said it once for the call's rows
                line = str(err)
            else:
                line = _one_line(err)
                logger.error("rsb serve: the policy failed on a request from %s: %s", _peer(ws), line,
                             exc_info=debug_enabled())  # the traceback in this log with rsb --debug only
            _send_error(ws, f"policy error: {line}", 1011)
        finally:
            if self.batcher is not None:
                self.batcher.close(conn)  # its rows' slots are free again

    def serve_forever(self) -> None:
        self._server.serve_forever()

    def start(self) -> "PolicyServer":
        self._thread = threading.Thread(target=self.serve_forever, name="rsb-policy-server", daemon=True)
        self._thread.start()
        return self

    def shutdown(self, timeout: float = 3.0) -> bool:
        """Stop serving: what waits on the policy fails first (a hung call included), then the connections
        close; False when they did not within ``timeout`` s (a client that does not answer the close)."""
        if self.batcher is not None:
            self.batcher.stop()
        closing = threading.Thread(target=self._server.shutdown, name="rsb-policy-server-close", daemon=True)
        closing.start()
        closing.join(timeout)
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        return not closing.is_alive()

    def __enter__(self) -> "PolicyServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


def serve_policy(policy: Any, host: str = "127.0.0.1", port: int = 8000, metadata: dict | None = None,
                 preset: Any = None, max_batch: int = DEFAULT_MAX_BATCH, max_wait_ms: float = DEFAULT_MAX_WAIT_MS,
                 parent_pid: int | None = None, token: str | None = None,
                 max_message_mb: float = DEFAULT_MAX_MESSAGE_MB, policy_timeout: float | None = None,
                 quiet: bool = False) -> None:
    """Serve ``policy`` until interrupted (Ctrl-C, SIGTERM, or ``parent_pid`` gone); blocks. Says how it
    serves once at start, prints the ready line (:data:`READY`) on stdout and the formed batch sizes at the
    end (``quiet``: only the ready line and errors). A stop takes at most a few seconds whatever the policy
    does (a call that hangs is left to die with the process); a second Ctrl-C exits at once."""
    try:
        server = PolicyServer(policy, host, port, metadata, preset=preset, max_batch=max_batch,
                              max_wait_ms=max_wait_ms, policy_timeout=policy_timeout, token=token,
                              max_message_mb=max_message_mb)
    except OSError as err:  # the port taken since the check before the policy loaded
        raise ServeError(f"cannot listen on {host}:{port}: {err.strerror or err} (another server there? pick "
                         "another --port; 0: a free one)") from None
    if not quiet:
        print(f"rsb serve: {server.describe()}", file=sys.stderr, flush=True)
    print(f"{READY} ws://{host}:{server.port}", flush=True)
    if not quiet and not parent_pid:  # a run's own server (on loopback) is nobody else's business
        print(_exposure(host, server.port, token), file=sys.stderr, flush=True)
    main_thread = threading.current_thread() is threading.main_thread()
    if parent_pid:
        threading.Thread(target=_watch_parent, args=(parent_pid, server, main_thread), name="rsb-parent-watch",
                         daemon=True).start()
    previous = signal.signal(signal.SIGTERM, _raise_interrupt) if main_thread else None
    closed = True
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        if main_thread:  # a second Ctrl-C while stopping: out at once
            signal.signal(signal.SIGINT, _exit_now)
            signal.signal(signal.SIGTERM, _exit_now)
        closed = server.shutdown(timeout=STOP_CLOSE_S)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if server.batcher is not None and not quiet:
            print(f"rsb serve: batches formed: {server.batcher.summary()}", file=sys.stderr, flush=True)
    if not closed and main_thread:  # connection threads still open would keep the process from exiting
        print(f"rsb serve: connections still open after {STOP_CLOSE_S:g} s: stopped without them", file=sys.stderr,
              flush=True)
        sys.stdout.flush()
        os._exit(0)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _exit_now(signum: int, frame: Any) -> None:
    sys.stderr.flush()
    os._exit(130)


def _watch_parent(pid: int, server: PolicyServer, main_thread: bool) -> None:
    """Stop serving when the process that started this server is gone (a server never outlives its run)."""
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != pid:
            if main_thread:
                os.kill(os.getpid(), signal.SIGTERM)  # a real signal wakes the main thread: it stops as on Ctrl-C
            else:
                server.shutdown()
            return


def quiet_logging() -> None:
    """Library log lines (websockets' "server listening", "connection open", tracebacks of dropped
    connections) are not the server's output: shown only with ``rsb --debug`` (``RSB_DEBUG=1``); the
    server's own warnings and errors are one line each."""
    debug = debug_enabled()
    logging.basicConfig(level=logging.INFO if debug else logging.WARNING, format="%(message)s")
    logging.getLogger("websockets").setLevel(logging.INFO if debug else logging.CRITICAL + 1)


def add_serve_args(p: argparse.ArgumentParser) -> None:
    """The arguments of ``rsb serve`` (and ``python -m rsb_maniskill.policies.remote.server``)."""
    p.add_argument("policy", help="built-in name or 'package.module:factory' returning an object with reset/act "
                                  "(and reset_batch/act_batch to batch), or infer, or a backbone's answer")
    p.add_argument("-a", "--policy-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="keyword argument of the policy factory (VALUE parsed as JSON, else a string); repeatable")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1: this machine only; "
                                                       "0.0.0.0: every interface, with --token)")
    p.add_argument("--token", default=None, help="clients must send this token (-a token=... of the remote policy; "
                                                 f"default ${TOKEN_ENV}, which keeps it out of the process list)")
    p.add_argument("--max-message-mb", type=float, default=DEFAULT_MAX_MESSAGE_MB, metavar="MB",
                   help="a request over this size ends its connection unread (default "
                        f"{DEFAULT_MAX_MESSAGE_MB:g}: 64 rows of three 320 x 240 cameras with depth fit)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000; 0: a free one, printed)")
    p.add_argument("--max-batch", type=int, default=DEFAULT_MAX_BATCH, metavar="B",
                   help=f"rows (envs) one policy call answers at most (default {DEFAULT_MAX_BATCH})")
    p.add_argument("--max-wait-ms", type=float, default=DEFAULT_MAX_WAIT_MS, metavar="T",
                   help="how long a request waits for others to join its batch, unless every client is in "
                        f"(default {DEFAULT_MAX_WAIT_MS:g})")
    p.add_argument("--policy-timeout", type=float, default=POLICY_TIMEOUT_S, metavar="SECONDS",
                   help="a policy call longer than this is taken for a hang: its clients get an error and later "
                        f"requests are refused until it returns (default {POLICY_TIMEOUT_S:g}, as rsb eval's; 0: "
                        "no limit)")
    p.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="requests and replies in this layout (openpi-aloha: openpi's Aloha keys, state and actions)")
    p.add_argument("--parent-pid", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help=argparse.SUPPRESS)  # rsb eval -q's own server: errors only


class ServeError(Exception):
    """The server cannot start where it was asked to (a port taken): one line, exit status 1."""


def check_serve_limits(max_batch: int, max_wait_ms: float, policy_timeout: float, port: int) -> None:
    """ValueError (one line, a usage error) for values no server runs with: before anything loads."""
    if not 1 <= max_batch <= MAX_BATCH_LIMIT:
        raise ValueError(f"--max-batch must be a number of rows from 1 to {MAX_BATCH_LIMIT}, got {max_batch}")
    if not 0 <= max_wait_ms <= MAX_WAIT_LIMIT_MS:  # NaN fails too
        raise ValueError(f"--max-wait-ms must be from 0 to {MAX_WAIT_LIMIT_MS:g} ms, got {max_wait_ms:g}")
    if not (0 <= policy_timeout and math.isfinite(policy_timeout)):
        raise ValueError(f"--policy-timeout must be a finite number of seconds >= 0 (0: no limit), got "
                         f"{policy_timeout:g}")
    if not 0 <= port <= 65535:
        raise ValueError(f"--port must be from 0 to 65535 (0: a free one), got {port}")


def _check_port(host: str, port: int) -> None:
    """ServeError when ``host:port`` cannot be listened on (taken, or not this machine's address), said
    before a model loads for minutes; websockets' own bind still decides."""
    if port == 0:
        return
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ServeError(f"--host {host}: not an address of this machine ({err.strerror})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server's own socket: TIME_WAIT is fine
        try:
            probe.bind(address)
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise ServeError(f"port {port} on {host} is taken (another server there?): stop it, or pick "
                                 "another --port (0: a free one, printed)") from None
            raise ServeError(f"cannot listen on {host}:{port}: {err.strerror or err}") from None


def run_server(args: argparse.Namespace) -> int:
    """Build the policy of ``args`` once and serve it; usage errors raise ValueError (one line), a port
    that cannot be had :class:`ServeError` (one line, before the policy loads)."""
    check_serve_limits(args.max_batch, args.max_wait_ms, args.policy_timeout, args.port)
    quiet_logging()
    max_message_bytes(args.max_message_mb, "--max-message-mb")  # before the policy loads
    kwargs = key_values(args.policy_arg, "-a")
    from rsb_maniskill.plugins import load_plugins

    load_plugins()  # a plugin's register_policy names, as `rsb eval` knows them
    if policy_spec(args.policy).needs_env:
        raise ValueError(f"policy {args.policy!r} is built with the env (it reads the simulator): it cannot be "
                         "served; run it with rsb eval")
    _check_port(args.host, args.port)
    policy = load_policy(args.policy, check=False, **kwargs)
    has_act = all(callable(getattr(policy, m, None)) for m in ("reset", "act"))
    built = f"{args.policy} built a {type(policy).__name__}"
    if args.preset and not has_act:
        raise ValueError(f"{built}, which has no reset()/act(): --preset adapts requests and replies for those")
    if not has_act and not is_batched(policy) and not any(callable(getattr(policy, m, None))
                                                          for m in ("infer", "answer")):
        raise ValueError(f"{built}, which has neither infer() nor reset()/act() (nor reset_batch()/act_batch(), "
                         "nor answer())")
    serve_policy(policy, args.host, args.port, preset=make_preset(args.preset) if args.preset else None,
                 max_batch=args.max_batch, max_wait_ms=args.max_wait_ms, policy_timeout=args.policy_timeout or None,
                 quiet=args.quiet, parent_pid=args.parent_pid, token=args.token or os.environ.get(TOKEN_ENV) or None,
                 max_message_mb=args.max_message_mb)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m rsb_maniskill.policies.remote.server",
                                description="Serve an RSB policy or backbone over openpi's websocket protocol, "
                                            "batching the requests of every client (as `rsb serve`)")
    add_serve_args(p)
    args = p.parse_args(argv)
    try:
        return run_server(args)
    except ValueError as err:
        p.error(str(err))
    except ServeError as err:
        print(f"rsb serve: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C while the policy loads
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
