"""An openpi-compatible websocket policy server that batches: one model for every client.

Serves an RSB :class:`~rsb_maniskill.policies.interface.Policy` (``reset``/``act``, and the batched
form ``reset_batch``/``act_batch``), an openpi-style object (``infer(obs: dict) -> dict`` with
``"actions"``) or a backbone (``answer``). Same wire protocol as openpi's ``WebsocketPolicyServer``
(see ``wire.py``), so openpi's client, :class:`RemotePolicy` and the vla-eval adapter talk to it.

An RSB policy is served by a :class:`~rsb_maniskill.policies.remote.batching.Batcher`: the
requests of every connection are gathered for at most ``max_wait_ms`` or ``max_batch`` rows (envs)
and answered by one ``act_batch`` over all their rows (a single-env policy: one row at a time);
``batching=False`` is the server of before (one request at a time under one lock), kept as the
benchmark's reference. ``infer`` and ``answer`` objects are served one request at a time.

Run one from the shell: ``rsb serve pkg.mod:make_policy --port 8000`` (or
``python -m rsb_maniskill.policies.remote.server pkg.mod:make_policy --port 8000``).
"""
from __future__ import annotations

import argparse
import hmac
import http
import ipaddress
import logging
import os
import signal
import sys
import threading
import time
from typing import Any

import numpy as np

from rsb_maniskill.debug import debug_enabled
from rsb_maniskill.policies.interface import as_chunk, as_chunks, is_batched, split_output, split_outputs
from rsb_maniskill.policies.registry import load_policy, policy_spec
from rsb_maniskill.policies.remote.batching import DEFAULT_MAX_BATCH, DEFAULT_MAX_WAIT_MS, Batcher, Request
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


def _request_obs(request: dict, prefix: str) -> Any:
    """The observation of a request: a flat "state" observation (one array under the prefix) as the
    array itself, as the policy gets it in-process; else the nested dict of its keys."""
    if prefix in request:
        return request[prefix]
    return unflatten_obs(request, prefix)


class PolicyAdapter:
    """openpi ``infer`` on top of an RSB Policy.

    The request's ``prompt`` is the instruction and the ``observation/...`` keys are un-flattened
    into the nested obs. The policy is reset on a connection's first request, when the request
    carries ``episode_start`` (``RemotePolicy(mark_episode_start=True)``), or when the prompt changes.
    With a ``preset`` (``openpi.OpenpiAloha``) the request is in openpi's Aloha layout instead,
    and so is the reply. A batched request (the prompt a list, see ``wire.py``) goes to the
    policy's batched form (``reset_batch`` / ``act_batch``), reset on the same rule. A policy that
    talks (returns ``{"actions": ..., "text": ...}``) gets its text sent as the reply's ``"text"``.
    """

    def __init__(self, policy: Any, prompt_key: str = "prompt", obs_prefix: str = "observation",
                 preset: Any = None) -> None:
        self.policy = policy
        self.prompt_key = prompt_key
        self.obs_prefix = obs_prefix
        self.preset = preset
        self._prompt: str | None = None

    def infer(self, request: dict) -> dict:
        request = dict(request)
        prompt = request.pop(self.prompt_key, "")
        prompt = prompt if isinstance(prompt, list) else str(prompt)
        start = bool(request.pop("episode_start", False))
        if isinstance(prompt, list):
            if self.preset:
                raise TypeError("the openpi-aloha preset takes one observation per request, not a batch")
            return self._infer_batch(prompt, start, request)
        obs = self.preset.obs_from_request(request) if self.preset else _request_obs(request, self.obs_prefix)
        if start or prompt != self._prompt:
            self.policy.reset(prompt, obs)
            self._prompt = prompt
        actions, text = split_output(self.policy.act(obs))
        chunk = as_chunk(actions)
        reply = {"actions": self.preset.aloha_actions(chunk) if self.preset else chunk}
        return reply if text is None else {**reply, "text": text}

    def _infer_batch(self, prompts: list, start: bool, request: dict) -> dict:
        if not is_batched(self.policy):
            raise TypeError(f"{type(self.policy).__name__} has no batched form (reset_batch / act_batch) for a "
                            "batched request; serve a batched policy or use RemotePolicy(batch=False)")
        envs = [int(e) for e in request.pop("env_ids", range(len(prompts)))]
        obs = _request_obs(request, self.obs_prefix)
        old = self._prompt if isinstance(self._prompt, list) else []
        if start or any(e >= len(old) or old[e] != p for e, p in zip(envs, prompts)):
            self.policy.reset_batch(prompts, obs)  # the first request of a wave holds every env
            self._prompt = list(prompts)
        actions, texts = split_outputs(self.policy.act_batch(obs, envs), len(envs))
        reply = {"actions": np.stack(as_chunks(actions, len(envs)))}
        return reply if all(t is None for t in texts) else {**reply, "text": texts}


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
    An RSB policy's requests are batched across connections (``max_batch`` rows, ``max_wait_ms``;
    ``batching=False``: one request at a time, the server of before); ``.batcher.sizes`` counts
    the rows of each policy call.
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
        batching: bool = True,
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
        self.batcher = Batcher(policy, max_batch, max_wait_ms) if batching and rsb_policy and not openpi_style \
            else None
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
        if callable(getattr(self.policy, "answer", None)) and not callable(getattr(self.policy, "act", None)):
            return BackboneAdapter(self.policy, self.prompt_key).infer
        # One adapter per connection: a new client starts a new episode.
        return PolicyAdapter(self.policy, self.prompt_key, self.obs_prefix, self.preset).infer

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

    def _batched_reply(self, conn: int, request: dict) -> dict:
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
                    reply = self._batched_reply(conn, request)
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

    def shutdown(self) -> None:
        self._server.shutdown()
        if self._thread is not None:
            self._thread.join(timeout=10)
        if self.batcher is not None:
            self.batcher.stop()

    def __enter__(self) -> "PolicyServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


def serve_policy(policy: Any, host: str = "127.0.0.1", port: int = 8000, metadata: dict | None = None,
                 preset: Any = None, max_batch: int = DEFAULT_MAX_BATCH, max_wait_ms: float = DEFAULT_MAX_WAIT_MS,
                 batching: bool = True, parent_pid: int | None = None, token: str | None = None,
                 max_message_mb: float = DEFAULT_MAX_MESSAGE_MB) -> None:
    """Serve ``policy`` until interrupted (Ctrl-C, SIGTERM, or ``parent_pid`` gone); blocks. Says how it
    serves once at start, prints the ready line (:data:`READY`) on stdout and the formed batch sizes at the end."""
    server = PolicyServer(policy, host, port, metadata, preset=preset, max_batch=max_batch, max_wait_ms=max_wait_ms,
                          batching=batching, token=token, max_message_mb=max_message_mb)
    print(f"rsb serve: {server.describe()}", file=sys.stderr, flush=True)
    logger.info("serving %s on ws://%s:%d", type(policy).__name__, host, server.port)
    print(f"{READY} ws://{host}:{server.port}", flush=True)
    print(_exposure(host, server.port, token), file=sys.stderr, flush=True)
    if parent_pid:
        threading.Thread(target=_watch_parent, args=(parent_pid, server), name="rsb-parent-watch",
                         daemon=True).start()
    previous = signal.signal(signal.SIGTERM, _raise_interrupt) \
        if threading.current_thread() is threading.main_thread() else None
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.shutdown()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if server.batcher is not None:
            print(f"rsb serve: batches formed: {server.batcher.summary()}", file=sys.stderr, flush=True)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _watch_parent(pid: int, server: PolicyServer) -> None:
    """Stop serving when the process that started this server is gone (a server never outlives its run)."""
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != pid:
            server._server.shutdown()
            return


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
    p.add_argument("--serial", action="store_true",
                   help="no batching: one request at a time (the server of before; a reference for benchmarks)")
    p.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="requests and replies in this layout (openpi-aloha: openpi's Aloha keys, state and actions)")
    p.add_argument("--parent-pid", type=int, default=None, help=argparse.SUPPRESS)


def run_server(args: argparse.Namespace) -> int:
    """Build the policy of ``args`` once and serve it; usage errors raise ValueError (one line)."""
    if args.max_batch < 1:
        raise ValueError(f"--max-batch must be >= 1 rows, got {args.max_batch}")
    if not args.max_wait_ms >= 0:
        raise ValueError(f"--max-wait-ms must be >= 0, got {args.max_wait_ms}")
    max_message_bytes(args.max_message_mb, "--max-message-mb")  # before the policy loads
    kwargs = key_values(args.policy_arg, "-a")
    from rsb_maniskill.plugins import load_plugins

    load_plugins()  # a plugin's register_policy names, as `rsb eval` knows them
    if policy_spec(args.policy).needs_env:
        raise ValueError(f"policy {args.policy!r} is built with the env (it reads the simulator): it cannot be "
                         "served; run it with rsb eval")
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
                 max_batch=args.max_batch, max_wait_ms=args.max_wait_ms, batching=not args.serial,
                 parent_pid=args.parent_pid, token=args.token or os.environ.get(TOKEN_ENV) or None,
                 max_message_mb=args.max_message_mb)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m rsb_maniskill.policies.remote.server",
                                description="Serve an RSB policy or backbone over openpi's websocket protocol, "
                                            "batching the requests of every client (as `rsb serve`)")
    add_serve_args(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    try:
        return run_server(args)
    except ValueError as err:
        p.error(str(err))
    except KeyboardInterrupt:  # Ctrl-C while the policy loads
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
