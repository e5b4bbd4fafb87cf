"""One policy, many clients: requests of every connection gathered into one forward pass.

The policy server (``server.py``) hands each decoded request to a :class:`Batcher`; one thread
gathers requests until ``max_batch`` rows (envs) are waiting, ``max_wait_ms`` have passed since the
first, or every open connection has one waiting (nobody else could join), then calls the policy
once over all their rows and hands each request its own rows back.

A row is one env of one connection (``(connection, env_id)``) and holds a slot: a fixed index into
the policy's batched form for as long as the connection lives. Episode starts reset only their
rows; rows that still hold actions of a chunk are not in any request, so they are not asked. An
episode start carries the episodes' seeds (``RemotePolicy`` passes on the runner's), given to a
``reset`` that takes ``seed`` (``reset_envs``: ``seeds``), so a seeded policy acts as in a worker.

- A batched policy (``reset_batch`` / ``act_batch``) gets one ``act_batch(obs, slots)`` per batch.
  Its starting rows reset with ``reset_envs(instructions, obs, slots)`` where it has that (the
  served batched form); without it, ``reset_batch`` over the whole slot table (each row its current
  instruction and latest observation), right for policies that keep no per-env state.
- A single-env policy (``reset`` / ``act``) is served one row at a time: the first row drives the
  object itself, every further row a shallow copy (:func:`row_copy`) whose containers and arrays
  are its own and whose model is shared: one copy of the weights, the episode state the row's own.

A batch that raises is retried request by request, so only the request whose rows fail gets the
error; the others get their actions.
"""
from __future__ import annotations

import collections
import copy
import inspect
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from rsb_maniskill.policies.interface import as_chunk, as_chunks, is_batched, split_output, split_outputs

DEFAULT_MAX_BATCH = 64  # rows (envs) a forward pass at most: 16 workers x 4 envs
DEFAULT_MAX_WAIT_MS = 25.0  # how long the first request of a batch waits for others: about half a 50 ms forward pass


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

    def __len__(self) -> int:
        return len(self.env_ids)


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


def takes_keyword(method: Any, name: str) -> bool:
    """Whether ``method`` accepts the keyword ``name`` (a reset's ``seed`` / ``seeds``)."""
    try:
        params = inspect.signature(method).parameters.values()
    except (TypeError, ValueError):
        return False
    return any((p.name == name and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)) or p.kind == p.VAR_KEYWORD
               for p in params)


def row_copy(policy: Any) -> Any:
    """A single-env policy for another row: a shallow copy whose containers and arrays (its episode
    state: a history deque, a pending chunk) are its own, every other attribute (the model, a
    tokenizer, an RNG) shared with ``policy``: one copy of the weights."""
    try:
        import torch

        shared: tuple[type, ...] = (torch.nn.Module, torch.Tensor)
    except ImportError:  # pragma: no cover - torch is a dependency
        shared = ()
    clone = copy.copy(policy)
    state = getattr(clone, "__dict__", None)
    if state is None:
        return clone
    memo: dict[int, Any] = {}
    for key, value in list(state.items()):
        if isinstance(value, (list, dict, set, collections.deque, np.ndarray)):
            for item in (value.values() if isinstance(value, dict) else
                         () if isinstance(value, np.ndarray) else value):
                if shared and isinstance(item, shared):
                    memo[id(item)] = item  # modules and tensors in a container stay shared
            state[key] = copy.deepcopy(value, memo)
    return clone


class Batcher:
    """Gathers :class:`Request` s of every connection and answers them with one policy call a batch.

    ``submit`` blocks the connection's thread until its rows are answered (or raises their error).
    ``sizes`` counts the rows of each policy call (the formed batch sizes).
    """

    def __init__(self, policy: Any, max_batch: int = DEFAULT_MAX_BATCH, max_wait_ms: float = DEFAULT_MAX_WAIT_MS,
                 log: Callable[[str], None] | None = None) -> None:
        if max_batch < 1:
            raise ValueError(f"max_batch must be >= 1 rows, got {max_batch}")
        if not max_wait_ms >= 0:
            raise ValueError(f"max_wait_ms must be >= 0, got {max_wait_ms}")
        self.policy = policy
        self.max_batch = int(max_batch)
        self.max_wait = float(max_wait_ms) / 1000.0
        self.batched = is_batched(policy)
        self.row_resets = self.batched and callable(getattr(policy, "reset_envs", None))
        self.sizes: collections.Counter[int] = collections.Counter()
        self._queue: queue.Queue[Request | None] = queue.Queue()
        self._lock = threading.Lock()
        self._open: set[int] = set()
        self._slots: dict[tuple[int, int], int] = {}
        self._free: list[int] = []
        self._prompts: dict[int, str] = {}  # slot -> its episode's instruction
        self._last_obs: dict[int, Any] = {}  # slot -> latest row (reset_batch over the table only)
        self._copies: dict[int, Any] = {}  # slot -> the single-env policy object of that row
        self._next_conn = 0
        self._thread = threading.Thread(target=self._loop, name="rsb-policy-batcher", daemon=True)
        self._thread.start()
        if log is not None:
            log(self.describe())

    def describe(self) -> str:
        name = type(self.policy).__name__
        if not self.batched:
            return (f"{name} has no batched form (reset_batch / act_batch): served one row at a time, each "
                    "further row a shallow copy of it (its model shared, its containers and arrays its own)")
        how = "reset_envs: episode starts reset their rows only" if self.row_resets else \
            "no reset_envs: an episode start calls reset_batch over every row"
        return (f"{name}: one act_batch a batch of up to {self.max_batch} rows gathered for at most "
                f"{self.max_wait * 1000:g} ms ({how})")

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
            for key in [k for k in self._slots if k[0] == conn]:
                slot = self._slots.pop(key)
                self._prompts.pop(slot, None)
                self._last_obs.pop(slot, None)
                self._copies.pop(slot, None)
                self._free.append(slot)

    def submit(self, request: Request) -> tuple[list[np.ndarray], list[str | None]]:
        self._queue.put(request)
        request.done.wait()
        if request.error is not None:
            raise request.error
        assert request.chunks is not None and request.texts is not None
        return request.chunks, request.texts

    def stop(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=10)

    def summary(self) -> str:
        """The formed batch sizes: ``calls, rows a call, {rows: calls}``."""
        calls = sum(self.sizes.values())
        rows = sum(k * v for k, v in self.sizes.items())
        mean = rows / calls if calls else 0.0
        return f"{calls} policy calls, {mean:.1f} rows a call; rows: calls {dict(sorted(self.sizes.items()))}"

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
            batch = self._gather(first, carry, carried)
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
            return slot, True

    def _answer(self, batch: list[Request]) -> None:
        groups: dict[tuple, list[Request]] = {}
        for r in batch:
            groups.setdefault(_signature(r.obs), []).append(r)
        for group in groups.values():
            try:
                self._run(group)
            except Exception as err:  # noqa: BLE001  (retried one request at a time: only its rows fail)
                if len(group) == 1:
                    group[0].error = err
                else:
                    for r in group:
                        try:
                            self._run([r])
                        except Exception as one:  # noqa: BLE001
                            r.error = one
            for r in group:
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
        if self.batched:
            chunks, texts = self._run_batched(obs, slots, starts, prompts, seeds)
        else:
            chunks, texts = self._run_rows(obs, slots, starts, prompts, seeds)
        self.sizes[len(slots)] += 1
        at = 0
        for r in group:
            r.chunks, r.texts = chunks[at:at + len(r)], texts[at:at + len(r)]
            at += len(r)

    def _run_batched(self, obs: Any, slots: list[int], starts: list[bool], prompts: list[str],
                     seeds: list[int | None]) -> tuple[list[np.ndarray], list[str | None]]:
        begin = [i for i, s in enumerate(starts) if s]
        if begin and self.row_resets:
            given = [seeds[i] for i in begin]
            extra = {"seeds": given} if None not in given and takes_keyword(self.policy.reset_envs, "seeds") else {}
            self.policy.reset_envs([prompts[i] for i in begin], take_rows(obs, begin), [slots[i] for i in begin],
                                   **extra)
        if not self.row_resets:
            for i, slot in enumerate(slots):
                self._last_obs[slot] = take_rows(obs, [i])
        if begin and not self.row_resets:
            table = max(self._last_obs) + 1
            fill = next(iter(self._last_obs.values()))
            self.policy.reset_batch([self._prompts.get(s, "") if s not in slots else prompts[slots.index(s)]
                                     for s in range(table)],
                                    stack_rows([self._last_obs.get(s, fill) for s in range(table)]))
        for i in begin:
            self._prompts[slots[i]] = prompts[i]
        actions, texts = split_outputs(self.policy.act_batch(obs, slots), len(slots))
        return as_chunks(actions, len(slots)), texts

    def _run_rows(self, obs: Any, slots: list[int], starts: list[bool], prompts: list[str],
                  seeds: list[int | None]) -> tuple[list[np.ndarray], list[str | None]]:
        chunks, texts = [], []
        for i, slot in enumerate(slots):
            policy = self._copies.get(slot)
            if policy is None:
                policy = self.policy if slot == 0 else row_copy(self.policy)
                self._copies[slot] = policy
            row = take_rows(obs, i)
            if starts[i]:
                if seeds[i] is not None and takes_keyword(policy.reset, "seed"):
                    policy.reset(prompts[i], row, seed=seeds[i])
                else:
                    policy.reset(prompts[i], row)
                self._prompts[slot] = prompts[i]
            actions, text = split_output(policy.act(row))
            chunks.append(as_chunk(actions))
            texts.append(text)
        return chunks, texts
