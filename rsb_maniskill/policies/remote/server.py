"""A minimal openpi-compatible websocket policy server.

Serves either an openpi-style object (``infer(obs: dict) -> dict`` with ``"actions"``) or an RSB
:class:`~rsb_maniskill.policies.interface.Policy` (``reset``/``act``), the latter through
:class:`PolicyAdapter`. Same wire protocol as openpi's ``WebsocketPolicyServer`` (see
``wire.py``), so openpi's client can talk to it and :class:`RemotePolicy` can talk to openpi.

Run one from the shell: ``python -m rsb_maniskill.policies.remote.server pkg.mod:make_policy --port 8000``.
"""
from __future__ import annotations

import argparse
import http
import logging
import threading
import time
import traceback
from typing import Any

import numpy as np

from rsb_maniskill.policies.interface import as_chunk, as_chunks, is_batched, split_output, split_outputs
from rsb_maniskill.policies.registry import load_policy
from rsb_maniskill.policies.remote.openpi import PRESETS, make_preset
from rsb_maniskill.policies.remote.wire import INSTALL_HINT, packb, unflatten_obs, unpackb

logger = logging.getLogger(__name__)


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
        obs = self.preset.obs_from_request(request) if self.preset else unflatten_obs(request, self.obs_prefix)
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
        obs = unflatten_obs(request, self.obs_prefix)
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


def _health_check(connection: Any, request: Any) -> Any:
    # `GET /healthz` -> 200, as openpi's server does; everything else goes on to the handshake.
    if getattr(request, "path", None) == "/healthz":
        return connection.respond(http.HTTPStatus.OK, "OK\n")
    return None


class PolicyServer:
    """Serve ``policy`` over websocket; ``port=0`` picks a free port (read it from ``.port``).

    ``start()`` serves from a background thread (tests, notebooks); ``serve_forever()`` blocks.
    Requests are handled one at a time, as one policy object holds one episode's state.
    """

    def __init__(
        self,
        policy: Any,
        host: str = "0.0.0.0",
        port: int = 8000,
        metadata: dict | None = None,
        prompt_key: str = "prompt",
        obs_prefix: str = "observation",
        preset: Any = None,
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
        self._server = serve(
            self._handle, host, port, compression=None, max_size=None, process_request=_health_check
        )
        self.host = host
        self.port = int(self._server.socket.getsockname()[1])

    def _infer_fn(self) -> Any:
        if self.preset is None and callable(getattr(self.policy, "infer", None)):
            return self.policy.infer
        if callable(getattr(self.policy, "answer", None)) and not callable(getattr(self.policy, "act", None)):
            return BackboneAdapter(self.policy, self.prompt_key).infer
        # One adapter per connection: a new client starts a new episode.
        return PolicyAdapter(self.policy, self.prompt_key, self.obs_prefix, self.preset).infer

    def _handle(self, ws: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        infer = self._infer_fn()
        ws.send(packb(self.metadata))
        while True:
            try:
                request = unpackb(ws.recv())
                t0 = time.monotonic()
                with self._lock:
                    reply = dict(infer(request))
                reply["server_timing"] = {"infer_ms": 1000.0 * (time.monotonic() - t0)}
                ws.send(packb(reply))
            except ConnectionClosed:
                return
            except Exception:
                # Like openpi: the traceback as a text frame, then close with 1011 (internal error).
                logger.exception("policy server: request failed")
                try:
                    ws.send(traceback.format_exc())
                    ws.close(code=1011, reason="Internal server error. Traceback included in previous frame.")
                except ConnectionClosed:
                    pass
                return

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

    def __enter__(self) -> "PolicyServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


def serve_policy(policy: Any, host: str = "0.0.0.0", port: int = 8000, metadata: dict | None = None,
                 preset: Any = None) -> None:
    """Serve ``policy`` until interrupted (blocks)."""
    server = PolicyServer(policy, host, port, metadata, preset=preset)
    logger.info("serving %s on ws://%s:%d", type(policy).__name__, host, server.port)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.shutdown()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Serve an RSB policy or backbone (module:factory) over openpi's "
                                            "websocket protocol")
    p.add_argument("policy", help="'package.module:factory' returning an object with reset/act (or infer), or a "
                                  "backbone with answer(instruction, images)")
    p.add_argument("--host", default="0.0.0.0")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="requests and replies in this layout (openpi-aloha: openpi's Aloha keys, state and actions)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    policy = load_policy(args.policy, check=False)
    has_act = all(callable(getattr(policy, m, None)) for m in ("reset", "act"))
    built = f"{args.policy} built a {type(policy).__name__}"
    if args.preset and not has_act:
        p.error(f"{built}, which has no reset()/act(): --preset adapts requests and replies for those")
    if not has_act and not is_batched(policy) and not any(callable(getattr(policy, m, None))
                                                          for m in ("infer", "answer")):
        p.error(f"{built}, which has neither infer() nor reset()/act() (nor reset_batch()/act_batch(), "
                "nor answer())")
    serve_policy(policy, args.host, args.port, preset=make_preset(args.preset) if args.preset else None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
