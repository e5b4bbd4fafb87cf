"""One policy, many clients: requests of every connection gathered into one forward pass.

The policy server (``server.py``) hands each decoded request to a :class:`Batcher`; one thread
gathers requests until ``max_batch`` rows (envs) are waiting, ``max_wait_ms`` have passed since the
first, or every open connection has one waiting (nobody else could join), then calls the policy
once over all their rows and hands each request its own rows back. A request of more rows than
``max_batch`` is answered in parts of at most ``max_batch`` rows, one call each.

A row is one env of one connection (``(connection, env_id)``) and holds a slot: a fixed index into
the policy's batched form for as long as the connection lives. Each row's episode state is its own,
whatever the policy:

- A batched policy (``reset_batch`` / ``act_batch``) must have ``reset_envs(instructions, obs,
  envs)`` (see :class:`~rsb_maniskill.policies.interface.BatchedPolicy`): the rows that start an
  episode are reset with it, and only they; the other rows go on. It gets one ``act_batch(obs,
  slots)`` per batch. Without ``reset_envs`` it is served by its single-env form when it has one,
  else refused (a ``reset_batch`` over every row would restart other clients' episodes).
- A single-env policy (``reset`` / ``act``) gets one object per row, made from the policy as built
  (which is never driven itself): its ``fork()`` where it defines one, else a deep copy whose torch
  modules (the weights) are shared by reference (:func:`row_policy`). Rows share nothing else: an
  RNG, a history, a wrapped inner policy are each row's own.

An episode start carries the episodes' seeds (``RemotePolicy`` passes on the runner's), given to a
``reset`` that takes ``seed`` (``reset_envs``: ``seeds``), so a seeded policy acts as in a worker.

Faults: a policy call that raises (anything, ``KeyboardInterrupt`` included) fails the requests of
its rows once, and says so in one line; it is never called again for rows that may have advanced,
and those rows start a new episode on their next request. A call that runs past ``policy_timeout``
fails its rows at the timeout; until it returns, every request is refused at once in one line (the
thread stuck in it cannot be stopped). ``stop`` fails whatever waits, so no connection waits on a
policy that will not answer.
"""
from __future__ import annotations

import collections
import copy
import math
import queue
import sys
import threading
import time
import traceback
import types
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from rsb_maniskill.debug import debug_enabled, plural
from rsb_maniskill.policies.interface import as_chunk, as_chunks, is_batched, split_output, split_outputs, takes_keyword

DEFAULT_MAX_BATCH = 64  # rows (envs) a forward pass at most: 16 workers x 4 envs
DEFAULT_MAX_WAIT_MS = 25.0  # how long the first request of a batch waits for others: about half a 50 ms forward pass
MAX_WAIT_LIMIT_MS = 60_000.0  # a longer wait is a typo (and past what a thread's timeout takes)
MAX_BATCH_LIMIT = 65_536  # rows a call: more is a typo
POLL_S = 0.1  # how often a waiting connection looks for a call past the policy timeout, or a stop


class ServedPolicyError(RuntimeError):
    """A request not answered: its policy call failed, ran past the policy timeout, or the server stops."""


@dataclass
class Request:
    """One request's rows: ``obs`` holds them with a leading row dim (a flat state array or a nested dict)."""

    conn: int
    env_ids: list[int]
    prompts: list[str]
    start: bool  # the client marked an episode start (every row of the request)
    obs: Any
    seeds: list[int] | None = None  # the starting episodes' seeds, one a row (given to a reset that takes them)
    arrived: float = field(default_factory=time.monotonic)
    done: threading.Event = field(default_factory=threading.Event)
    chunks: list[np.ndarray] | None = None
    texts: list[str | None] | None = None
    error: BaseException | None = None
    whole: "Request | None" = None  # a part of a request split at max_batch rows: the request it belongs to

    def __len__(self) -> int:
        return len(self.env_ids)

    def split(self, rows: int) -> list["Request"]:
        """This request as parts of at most ``rows`` rows (itself when it fits)."""
        if len(self) <= rows:
            return [self]
        parts = []
        for lo in range(0, len(self), rows):
            hi = min(lo + rows, len(self))
            parts.append(Request(self.conn, self.env_ids[lo:hi], self.prompts[lo:hi], self.start,
                                 take_rows(self.obs, range(lo, hi)),
                                 None if self.seeds is None else self.seeds[lo:hi], self.arrived, whole=self))
        return parts


def _leaves(obs: Any, path: str = "") -> list[tuple[str, Any]]:
    if isinstance(obs, Mapping):
        return [leaf for k in sorted(obs) for leaf in _leaves(obs[k], f"{path}/{k}")]
    return [(path, obs)]


def _signature(obs: Any) -> tuple:
    """What must agree for rows to stack: keys, per-row shapes and dtypes."""
    return tuple((p, np.shape(v)[1:], np.asarray(v).dtype.str) for p, v in _leaves(obs))


def stack_rows(parts: Sequence[Any]) -> Any:
    """Batched observations (same structure) concatenated along their leading row dim."""
    if isinstance(parts[0], Mapping):
        return {k: stack_rows([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate([np.asarray(p) for p in parts]) if len(parts) > 1 else np.asarray(parts[0])


def take_rows(obs: Any, rows: Sequence[int] | int) -> Any:
    """Rows ``rows`` of a batched observation (one row without its leading dim when ``rows`` is an int)."""
    if isinstance(obs, Mapping):
        return {k: take_rows(v, rows) for k, v in obs.items()}
    return np.asarray(obs)[rows if isinstance(rows, int) else list(rows)]


_ATOMS = (str, bytes, int, float, bool, np.ndarray, type, types.ModuleType, types.FunctionType,
          types.BuiltinFunctionType)  # nothing to look for inside (deepcopy keeps code as it is)


def _shared_modules(obj: Any, found: dict[int, Any], seen: set[int], depth: int = 0) -> None:
    """The torch modules reachable from ``obj`` through attributes and containers, by id."""
    import torch

    if id(obj) in seen or depth > 50 or obj is None or isinstance(obj, _ATOMS):
        return
    seen.add(id(obj))
    if isinstance(obj, types.MethodType):  # deepcopy copies a bound method's object
        obj = obj.__self__
    if isinstance(obj, torch.nn.Module):
        found[id(obj)] = obj
        return
    if isinstance(obj, Mapping):
        items: Any = list(obj.values())
    elif isinstance(obj, (list, tuple, set, frozenset, collections.deque)):
        items = list(obj)
    else:
        items = list(getattr(obj, "__dict__", {}).values())
        for name in getattr(type(obj), "__slots__", ()):
            if hasattr(obj, name):
                items.append(getattr(obj, name))
    for item in items:
        _shared_modules(item, found, seen, depth + 1)


def row_policy(template: Any) -> Any:
    """A single-env policy for one more env (row): ``template.fork()`` where the policy defines it,
    else a deep copy of ``template`` whose torch modules are ``template``'s own objects (one copy of
    the weights); everything else (an RNG, a history, a wrapped policy, a scheduler) is the row's own."""
    fork = getattr(template, "fork", None)
    if callable(fork):
        return fork()
    memo: dict[int, Any] = {}
    try:
        _shared_modules(template, memo, set())
    except ImportError:  # pragma: no cover - torch is a dependency
        pass
    return copy.deepcopy(template, memo)


@dataclass
class _Call:
    """The policy call in progress: its parts, when it began, and whether the timeout cut it."""

    parts: list[Request]
    method: str
    started: float = field(default_factory=time.monotonic)
    cut: bool = False


def _check_limits(max_batch: int, max_wait_ms: float, policy_timeout: float | None) -> None:
    if isinstance(max_batch, bool) or not isinstance(max_batch, int) or not 1 <= max_batch <= MAX_BATCH_LIMIT:
        raise ValueError(f"max_batch must be a whole number of rows from 1 to {MAX_BATCH_LIMIT}, got {max_batch!r}")
    if not 0 <= max_wait_ms <= MAX_WAIT_LIMIT_MS:  # NaN fails both
        raise ValueError(f"max_wait_ms must be between 0 and {MAX_WAIT_LIMIT_MS:g} ms, got {max_wait_ms!r}")
    if policy_timeout is not None and not (0 < policy_timeout and math.isfinite(policy_timeout)):
        raise ValueError(f"policy_timeout must be a finite number of seconds > 0 (None: no limit), got "
                         f"{policy_timeout!r}")


def _stderr(line: str) -> None:
    print(f"rsb serve: {line}", file=sys.stderr, flush=True)


class Batcher:
    """Gathers :class:`Request` s of every connection and answers them with one policy call a batch.

    ``submit`` blocks the connection's thread until its rows are answered (or raises their error,
    a :class:`ServedPolicyError`). ``sizes`` counts the rows of each policy call (the formed batch
    sizes). ``log`` gets the batcher's lines (how it serves, a failed or cut call): stderr by default.
    ValueError (one line) for limits out of range or a policy it cannot serve.
    """

    def __init__(self, policy: Any, max_batch: int = DEFAULT_MAX_BATCH, max_wait_ms: float = DEFAULT_MAX_WAIT_MS,
                 log: Callable[[str], None] | None = None, policy_timeout: float | None = None) -> None:
        _check_limits(max_batch, max_wait_ms, policy_timeout)
        self.policy = policy
        self.max_batch = int(max_batch)
        self.max_wait = float(max_wait_ms) / 1000.0
        self.policy_timeout = policy_timeout
        self.log = log or _stderr
        single = all(callable(getattr(policy, m, None)) for m in ("reset", "act"))
        row_resets = callable(getattr(policy, "reset_envs", None))
        self.batched = is_batched(policy) and (row_resets or not single)
        if self.batched and not row_resets:
            raise ValueError(f"{type(policy).__name__} has reset_batch / act_batch but no reset_envs(instructions, "
                             "obs, envs): served to many clients it must reset only the envs that start (a "
                             "reset_batch would restart every client's episodes); add reset_envs, or reset / act")
        if not self.batched and not single:
            raise ValueError(f"{type(policy).__name__} has neither reset_envs / reset_batch / act_batch nor reset / "
                             "act: nothing to serve")
        self.sizes: collections.Counter[int] = collections.Counter()
        self._queue: queue.Queue[Request | None] = queue.Queue()
        self._lock = threading.Lock()
        self._open: set[int] = set()
        self._slots: dict[tuple[int, int], int] = {}
        self._free: list[int] = []
        self._prompts: dict[int, str] = {}  # slot -> its episode's instruction
        self._rows: dict[int, Any] = {}  # slot -> the single-env policy object of that row
        self._spare: list[Any] = []
        if not self.batched:  # a row made now: a policy that cannot be copied is refused at start, not mid-run
            try:
                self._spare.append(row_policy(policy))
            except Exception as err:  # noqa: BLE001  (whatever deepcopy raises: said in one line)
                raise ValueError(f"{type(policy).__name__} cannot be copied for each env it serves "
                                 f"({type(err).__name__}: {err}); define fork() returning a new policy for another "
                                 "env, sharing its weights") from None
        self._call: _Call | None = None
        self._stopping = False
        self._next_conn = 0
        self._thread = threading.Thread(target=self._loop, name="rsb-policy-batcher", daemon=True)
        self._thread.start()

    def describe(self) -> str:
        name = type(self.policy).__name__
        limit = f"; a call over {self.policy_timeout:g} s fails its rows" if self.policy_timeout else ""
        if not self.batched:
            made = "its fork()" if callable(getattr(self.policy, "fork", None)) else \
                "a copy of the policy as built, its torch modules shared"
            return (f"{name} has no batched form with reset_envs: served one env at a time, each env its own "
                    f"({made}){limit}")
        return (f"{name}: one act_batch a batch of up to {self.max_batch} rows gathered for at most "
                f"{self.max_wait * 1000:g} ms; episode starts reset their rows only (reset_envs){limit}")

    # ------------------------------------------------------------ connections
    def open(self) -> int:
        with self._lock:
            conn = self._next_conn
            self._next_conn += 1
            self._open.add(conn)
        return conn

    def close(self, conn: int) -> None:
        """A connection ended: its slots go back to the pool (their next user starts an episode)."""
        with self._lock:
            self._open.discard(conn)
            self._forget([k for k in self._slots if k[0] == conn])

    def _forget(self, keys: Sequence[tuple[int, int]]) -> None:
        """Rows whose episode state is gone (under the lock): their next request starts anew."""
        for key in keys:
            slot = self._slots.pop(key, None)
            if slot is None:
                continue
            self._prompts.pop(slot, None)
            self._rows.pop(slot, None)
            self._free.append(slot)

    def submit(self, request: Request) -> tuple[list[np.ndarray], list[str | None]]:
        refused = self._refusal()
        if refused is not None:
            raise refused
        parts = request.split(self.max_batch)
        for part in parts:
            self._queue.put(part)
        for part in parts:
            while not part.done.wait(POLL_S):
                self._cut_overdue()
                refused = self._refusal()
                if refused is not None:
                    self._fail([part], refused)
            if part.error is not None:
                self._fail(parts, part.error)  # the parts not yet called are not called
                raise part.error
        if len(parts) == 1:
            assert request.chunks is not None and request.texts is not None
            return request.chunks, request.texts
        return [c for p in parts for c in p.chunks or ()], [t for p in parts for t in p.texts or ()]

    def stop(self) -> None:
        """Fail what waits, end the thread (not waiting long for a policy call that hangs: it is a daemon)."""
        with self._lock:
            self._stopping = True
            call = self._call
        if call is not None:
            self._fail(call.parts, ServedPolicyError("the policy server is stopping"))
        self._queue.put(None)
        self._thread.join(timeout=1.0)

    def summary(self) -> str:
        """The formed batch sizes: ``calls, rows a call, {rows: calls}``."""
        calls = sum(self.sizes.values())
        rows = sum(k * v for k, v in self.sizes.items())
        mean = rows / calls if calls else 0.0
        return f"{calls} policy calls, {mean:.1f} rows a call; rows: calls {dict(sorted(self.sizes.items()))}"

    # ------------------------------------------------------------ faults
    def _refusal(self) -> ServedPolicyError | None:
        """Why a request cannot be answered now (the server stops, or a call is stuck past the timeout)."""
        with self._lock:
            if self._stopping:
                return ServedPolicyError("the policy server is stopping")
            call = self._call
            if call is not None and call.cut:
                return ServedPolicyError(
                    f"the policy is still in the {call.method} call that ran past the policy timeout "
                    f"({self.policy_timeout:g} s), {time.monotonic() - call.started:.0f} s so far: no request is "
                    "answered until it returns (restart the server, or fix the policy)")
        return None

    def _cut_overdue(self) -> None:
        """A call past the policy timeout: its rows fail now, in one line (its thread cannot be stopped)."""
        if not self.policy_timeout:
            return
        with self._lock:
            call = self._call
            if call is None or call.cut or time.monotonic() - call.started <= self.policy_timeout:
                return
            call.cut = True
        rows = sum(len(p) for p in call.parts)
        err = ServedPolicyError(f"the policy's {call.method} call ran past the policy timeout "
                                f"({self.policy_timeout:g} s; a hang?): its {plural(rows, 'row')} fail")
        self.log(f"{err}; requests are refused until it returns")
        self._fail(call.parts, err)

    def _fail(self, parts: Sequence[Request], err: BaseException) -> None:
        """Fail ``parts`` (and the requests they are parts of) with ``err``, once; their rows start anew."""
        with self._lock:
            for part in parts:
                for r in (part, part.whole) if part.whole is not None else (part,):
                    if r.error is None and not r.done.is_set():
                        r.error = err
                    self._forget([(r.conn, e) for e in r.env_ids])
                part.done.set()

    # ------------------------------------------------------------ gathering
    def _gather(self, first: Request, carry: collections.deque, carried: bool = False) -> list[Request]:
        batch, rows = [first], len(first)
        # a request left over from a full batch has waited its turn: it takes only what is queued already
        deadline = time.monotonic() if carried else first.arrived + self.max_wait
        while rows < self.max_batch:
            with self._lock:
                waiting_all = self._open <= {r.conn for r in batch}
            if waiting_all:
                break  # every open connection is in: nobody else can join
            try:
                nxt = carry.popleft() if carry else self._queue.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            if nxt is None:
                carry.append(None)
                break
            if rows + len(nxt) > self.max_batch:
                carry.appendleft(nxt)  # the next batch's first
                break
            batch.append(nxt)
            rows += len(nxt)
        return batch

    def _loop(self) -> None:
        carry: collections.deque = collections.deque()
        while True:
            carried = bool(carry)
            first = carry.popleft() if carried else self._queue.get()
            if first is None:
                return
            batch = [r for r in self._gather(first, carry, carried) if not r.done.is_set()]  # not failed meanwhile
            if batch:
                self._answer(batch)

    # ------------------------------------------------------------ calling the policy
    def _slot(self, conn: int, env: int) -> tuple[int, bool]:
        with self._lock:
            key = (conn, env)
            if key in self._slots:
                return self._slots[key], False
            slot = min(self._free) if self._free else len(self._slots)
            if self._free:
                self._free.remove(slot)
            self._slots[key] = slot
            self._rows.pop(slot, None)  # a new row: a fresh policy object, whatever a cut call left there
            self._prompts.pop(slot, None)
            return slot, True

    def _answer(self, batch: list[Request]) -> None:
        groups: dict[tuple, list[Request]] = {}
        for r in batch:
            groups.setdefault(_signature(r.obs), []).append(r)
        for group in groups.values():
            with self._lock:
                group = [r for r in group if not r.done.is_set()]  # a part whose request failed meanwhile: not called
                stopping = self._stopping
                if group and not stopping:
                    self._call = _Call(group, "act_batch" if self.batched else "reset/act")
            if stopping:
                self._fail(group, ServedPolicyError("the policy server is stopping"))
            if stopping or not group:
                continue
            try:
                self._run(group)
            except BaseException as err:  # noqa: BLE001  (KeyboardInterrupt, SystemExit too: the thread lives on)
                self._failed(group, err)
            finally:
                with self._lock:
                    call, self._call = self._call, None
                if call is not None and call.cut:
                    self.log(f"the {call.method} call that ran past the policy timeout returned after "
                             f"{time.monotonic() - call.started:.0f} s; answering requests again")

    def _failed(self, parts: list[Request], err: BaseException) -> None:
        """A policy call raised: its rows fail once, never called again; one line (the traceback with --debug)."""
        with self._lock:
            cut = self._call is not None and self._call.cut
        if cut:
            return  # failed at the timeout already
        rows = sum(len(p) for p in parts)
        what = f"{type(err).__name__}: {' '.join(str(err).split())}" if str(err) else type(err).__name__
        line = (f"the policy's {'act_batch' if self.batched else 'reset/act'} call raised {what}: its "
                f"{plural(rows, 'row')} ({plural(len(parts), 'request')}) fail, not called again")
        if debug_enabled():
            print("".join(traceback.format_exception(type(err), err, err.__traceback__)).rstrip(), file=sys.stderr)
        self.log(line)
        self._fail(parts, ServedPolicyError(f"the policy raised {what}"))

    def _finish(self, parts: list[Request], results: list[tuple[np.ndarray, str | None]]) -> None:
        """Hand each part its rows' chunks (unless the timeout failed them already)."""
        with self._lock:
            if self._call is not None and self._call.cut:
                return
            at = 0
            for r in parts:
                mine = results[at:at + len(r)]
                at += len(r)
                r.chunks, r.texts = [c for c, _ in mine], [t for _, t in mine]
                r.done.set()

    def _run(self, group: list[Request]) -> None:
        slots, starts, prompts, seeds = [], [], [], []
        for r in group:
            for k, (env, prompt) in enumerate(zip(r.env_ids, r.prompts)):
                slot, new = self._slot(r.conn, env)
                slots.append(slot)
                starts.append(r.start or new or self._prompts.get(slot) != prompt)
                prompts.append(prompt)
                seeds.append(r.seeds[k] if r.seeds is not None and k < len(r.seeds) else None)
        obs = stack_rows([r.obs for r in group])
        self.sizes[len(slots)] += 1  # counted as it starts: a call that hangs is one too
        if self.batched:
            results = self._run_batched(obs, slots, starts, prompts, seeds)
        else:
            results = self._run_rows(group, obs, slots, starts, prompts, seeds)
        if results is not None:
            self._finish(group, results)

    def _run_batched(self, obs: Any, slots: list[int], starts: list[bool], prompts: list[str],
                     seeds: list[int | None]) -> list[tuple[np.ndarray, str | None]]:
        begin = [i for i, s in enumerate(starts) if s]
        if begin:
            given = [seeds[i] for i in begin]
            extra = {"seeds": given} if None not in given and takes_keyword(self.policy.reset_envs, "seeds") else {}
            self.policy.reset_envs([prompts[i] for i in begin], take_rows(obs, begin), [slots[i] for i in begin],
                                   **extra)
            for i in begin:
                self._prompts[slots[i]] = prompts[i]
        actions, texts = split_outputs(self.policy.act_batch(obs, slots), len(slots))
        return list(zip(as_chunks(actions, len(slots)), texts))

    def _run_rows(self, group: list[Request], obs: Any, slots: list[int], starts: list[bool], prompts: list[str],
                  seeds: list[int | None]) -> list[tuple[np.ndarray, str | None]] | None:
        """Each row by its own policy object; a row that raises fails its request only (the rows are
        independent objects), the other requests' rows are answered."""
        results: list[Any] = []
        owner = [r for r in group for _ in range(len(r))]
        failed: dict[int, BaseException] = {}  # id(request) -> what its row raised
        for i, slot in enumerate(slots):
            if id(owner[i]) in failed:
                results.append(None)
                continue
            try:
                results.append(self._row_step(obs, i, slot, starts[i], prompts[i], seeds[i]))
            except BaseException as err:  # noqa: BLE001  (KeyboardInterrupt, SystemExit too: the thread lives on)
                failed[id(owner[i])] = err
                results.append(None)
        if not failed:
            return results
        bad = [r for r in group if id(r) in failed]
        for r in bad:
            self._failed([r], failed[id(r)])
        at, good, kept = 0, [], []
        for r in group:
            if id(r) not in failed:
                good.append(r)
                kept += results[at:at + len(r)]
            at += len(r)
        if good:
            self._finish(good, kept)
        return None

    def _row_step(self, obs: Any, i: int, slot: int, start: bool, prompt: str,
                  seed: int | None) -> tuple[np.ndarray, str | None]:
        policy = self._rows.get(slot)
        if policy is None:
            policy = self._spare.pop() if self._spare else row_policy(self.policy)
            self._rows[slot] = policy
            start = True
        row = take_rows(obs, i)
        if start:
            if seed is not None and takes_keyword(policy.reset, "seed"):
                policy.reset(prompt, row, seed=seed)
            else:
                policy.reset(prompt, row)
            self._prompts[slot] = prompt
        actions, text = split_output(policy.act(row))
        return as_chunk(actions), text
