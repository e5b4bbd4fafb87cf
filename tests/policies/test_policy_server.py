"""The batching policy server (``policies/remote/batching.py``, ``server.py``, ``rsb serve``): the rows of
every connection in one policy call, each connection its own rows back, resets of the starting rows
only, and its faults: a policy that raises on one row, a client that leaves mid-batch. Servers bind
127.0.0.1 and stop with the test."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("websockets")
pytest.importorskip("msgpack")

from counted_policies import HORIZON, CountedPolicy, CountedSingle, _action  # noqa: E402

from rsb_maniskill.policies.remote.batching import Batcher, Request, row_policy  # noqa: E402
from rsb_maniskill.policies.remote.client import RemotePolicy  # noqa: E402
from rsb_maniskill.policies.remote.server import READY, PolicyServer  # noqa: E402

HELPERS = Path(__file__).parents[1] / "helpers"
OBS_DIM = 5
WAIT_FOREVER_MS = 60_000.0  # a batch closes when every open connection is in, not on the clock


def _obs(rows: int, base: float) -> np.ndarray:
    return (base + np.arange(rows * OBS_DIM, dtype=np.float32).reshape(rows, OBS_DIM)) / 100


def _submit_all(batcher: Batcher, requests: list[Request]) -> list:
    out: list = [None] * len(requests)

    def one(i: int) -> None:
        try:
            out[i] = batcher.submit(requests[i])
        except Exception as err:  # noqa: BLE001  (the test reads it)
            out[i] = err

    threads = [threading.Thread(target=one, args=(i,)) for i in range(len(requests))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    return out


def test_rows_of_every_connection_in_one_call_each_gets_its_own(tmp_path):
    policy = CountedPolicy(str(tmp_path / "loads"))
    batcher = Batcher(policy, max_batch=64, max_wait_ms=WAIT_FOREVER_MS)
    conns = [batcher.open() for _ in range(3)]
    obs = [_obs(2, 0), _obs(3, 50), _obs(1, 90)]
    requests = [Request(c, list(range(len(o))), ["p"] * len(o), True, o) for c, o in zip(conns, obs)]
    out = _submit_all(batcher, requests)
    batcher.stop()
    assert batcher.sizes == {6: 1}  # 2 + 3 + 1 rows, one act_batch
    for o, (chunks, texts) in zip(obs, out):
        assert len(chunks) == len(o) and texts == [None] * len(o)
        for row, chunk in zip(o, chunks):  # each connection got its own rows, in its order
            assert np.array_equal(chunk, _action(row))
    # every row started in that batch: one reset over the six slots, none twice
    assert sorted(s for r in policy.row_resets for s in r) == list(range(6))


def test_max_batch_splits_and_episode_starts_reset_only_their_rows(tmp_path):
    policy = CountedPolicy(str(tmp_path / "loads"))
    batcher = Batcher(policy, max_batch=3, max_wait_ms=WAIT_FOREVER_MS)
    a, b = batcher.open(), batcher.open()
    _submit_all(batcher, [Request(a, [0, 1], ["x", "x"], True, _obs(2, 0)),
                          Request(b, [0, 1], ["y", "y"], True, _obs(2, 9))])
    assert sorted(batcher.sizes.elements()) == [2, 2]  # 4 rows > max_batch 3: two calls
    policy.row_resets.clear()
    # a new episode on connection b only; a goes on (no start, same prompt): only b's slots reset
    _submit_all(batcher, [Request(a, [0, 1], ["x", "x"], False, _obs(2, 1)),
                          Request(b, [0, 1], ["z", "z"], True, _obs(2, 2))])
    slots_b = sorted(batcher._slots[(b, e)] for e in (0, 1))
    assert policy.row_resets == [slots_b]
    batcher.close(a)  # a and b leave: their slots are free, the next connection takes one and starts on it
    batcher.close(b)
    c = batcher.open()
    policy.row_resets.clear()
    _submit_all(batcher, [Request(c, [0], ["w"], False, _obs(1, 3))])
    assert policy.row_resets == [[0]]
    batcher.stop()


def test_a_failing_batch_fails_its_rows_once_and_they_start_anew(tmp_path):
    """One act_batch raised: every request of that call fails, in one line, and the call is not made
    again over rows that may have advanced; those rows start a new episode on their next request."""
    poison = _obs(1, 40)
    policy = CountedPolicy(str(tmp_path / "loads"), fail_on=float(poison.sum()))
    calls = []
    act_batch = policy.act_batch
    policy.act_batch = lambda obs, envs: (calls.append(list(envs)), act_batch(obs, envs))[1]
    lines: list[str] = []
    batcher = Batcher(policy, max_batch=64, max_wait_ms=WAIT_FOREVER_MS, log=lines.append)
    conns = [batcher.open() for _ in range(3)]
    obs = [_obs(2, 0), np.concatenate([_obs(1, 7), poison]), _obs(1, 80)]
    out = _submit_all(batcher, [Request(c, list(range(len(o))), ["p"] * len(o), True, o) for c, o in zip(conns, obs)])
    assert all(isinstance(o, RuntimeError) and "poison" in str(o) for o in out), out
    assert len(calls) == 1  # never re-run over the rows
    assert len(lines) == 1 and "5 rows (3 requests) fail" in lines[0] and "poison" in lines[0], lines
    policy.row_resets.clear()
    batcher.close(conns[1])
    batcher.close(conns[2])
    chunks, _ = _submit_all(batcher, [Request(conns[0], [0, 1], ["p", "p"], False, _obs(2, 1))])[0]
    assert [c.tolist() for c in chunks] == [_action(r).tolist() for r in _obs(2, 1)]
    assert len(policy.row_resets) == 1 and len(policy.row_resets[0]) == 2  # no start marked: reset anyway
    batcher.stop()


def test_a_single_env_row_that_raises_fails_its_request_only(tmp_path):
    """Rows of a single-env policy are objects of their own: one that raises fails its request, the
    other requests of that batch get their actions."""
    class Fussy(CountedSingle):
        def act(self, obs):
            if float(np.asarray(obs).sum()) < 0:
                raise ValueError("negative observation")
            return super().act(obs)

    lines: list[str] = []
    batcher = Batcher(Fussy(str(tmp_path / "loads")), max_batch=64, max_wait_ms=WAIT_FOREVER_MS, log=lines.append)
    conns = [batcher.open() for _ in range(3)]
    obs = [_obs(1, 0), -_obs(1, 5), _obs(1, 9)]
    out = _submit_all(batcher, [Request(c, [0], ["p"], True, o) for c, o in zip(conns, obs)])
    batcher.stop()
    assert isinstance(out[1], RuntimeError) and "negative observation" in str(out[1])
    assert [out[i][0][0].tolist() for i in (0, 2)] == [(_action(obs[i][0]) + 0.001).tolist() for i in (0, 2)]
    assert len(lines) == 1 and "ValueError: negative observation" in lines[0]


def test_single_env_policy_one_row_at_a_time_each_row_its_own_state(tmp_path):
    """Two connections' episodes interleaved on one single-env object give what each gets alone."""
    def alone(obs_seq):
        p = CountedSingle(str(tmp_path / "alone"))
        p.reset("p", obs_seq[0])
        return [p.act(o) for o in obs_seq]

    seqs = [[_obs(1, 10 * k + i)[0] for i in range(4)] for k in range(2)]
    policy = CountedSingle(str(tmp_path / "loads"))
    batcher = Batcher(policy, max_batch=64, max_wait_ms=WAIT_FOREVER_MS)
    conns = [batcher.open() for _ in seqs]
    got: list[list] = [[], []]
    for step in range(4):
        out = _submit_all(batcher, [Request(c, [0], ["p"], step == 0, s[step][None]) for c, s in zip(conns, seqs)])
        for k, (chunks, _) in enumerate(out):
            got[k].append(chunks[0])
    batcher.stop()
    for k in range(2):
        assert [g.tolist() for g in got[k]] == [a.tolist() for a in alone(seqs[k])]
    assert "one env at a time" in batcher.describe()
    assert (tmp_path / "loads").read_text().count("\n") == 1  # the copies load nothing


def test_a_row_shares_the_weights_and_nothing_mutable():
    """A row of a single-env policy: its torch modules are the template's, its RNG, history, scheduler
    and wrapped inner policy its own (drawing from one row's generator leaves the other's alone)."""
    import torch

    class Inner:
        def __init__(self):
            self.net = torch.nn.Linear(2, 2)
            self.gen = torch.Generator().manual_seed(1)
            self.history = [1.0]
            self.steps = {"t": torch.zeros(3)}

    class Wrapper:
        def __init__(self):
            self.inner = Inner()
            self.encode = self.inner.net.forward  # a bound method of a module: the module stays shared

    p = Wrapper()
    q = row_policy(p)
    assert q.inner is not p.inner and q.inner.net is p.inner.net and q.encode.__self__ is p.inner.net
    assert q.inner.gen is not p.inner.gen and q.inner.history == [1.0] and q.inner.history is not p.inner.history
    assert q.inner.steps["t"] is not p.inner.steps["t"]
    first = torch.randn(2, generator=q.inner.gen)
    assert torch.equal(torch.randn(2, generator=p.inner.gen), first)  # the template's own draw is untouched

    class Forked(Wrapper):
        def fork(self):
            return "forked"

    assert row_policy(Forked()) == "forked"  # the policy's own way to make a row


def test_a_batched_policy_without_reset_envs_is_served_by_its_single_form_or_refused(tmp_path):
    class NoRowResets(CountedPolicy):
        reset_envs = None

    class BatchedOnly:
        def reset_batch(self, instructions, obs):
            pass

        def act_batch(self, obs, envs):
            return np.zeros((len(envs), 1, 14))

    batcher = Batcher(NoRowResets(str(tmp_path / "loads")))
    assert not batcher.batched and "one env at a time" in batcher.describe()
    batcher.stop()
    with pytest.raises(ValueError, match="no reset_envs"):
        Batcher(BatchedOnly())


def test_max_batch_1_never_forms_two_row_calls(tmp_path):
    """A request of more rows than max_batch is answered in parts of max_batch rows, one call each."""
    policy = CountedPolicy(str(tmp_path / "loads"))
    batcher = Batcher(policy, max_batch=1, max_wait_ms=WAIT_FOREVER_MS)
    conns = [batcher.open() for _ in range(2)]
    obs = [_obs(3, 0), _obs(2, 30)]
    out = _submit_all(batcher, [Request(c, list(range(len(o))), ["p"] * len(o), True, o) for c, o in zip(conns, obs)])
    batcher.stop()
    assert batcher.sizes == {1: 5}
    for o, (chunks, _) in zip(obs, out):
        assert [c.tolist() for c in chunks] == [_action(r).tolist() for r in o]


def test_client_that_leaves_mid_batch_does_not_stop_the_others(tmp_path):
    """Client A sends and closes while its batch is computed; B gets its actions, C connects after."""
    policy = CountedPolicy(str(tmp_path / "loads"), delay_s=0.5)
    # B stays connected, idle, while C asks: C's batch closes on the clock (50 ms), not on B
    with PolicyServer(policy, host="127.0.0.1", port=0, max_wait_ms=50) as server:
        a = RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10)
        b = RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10)
        a._ws.send(__import__("rsb_maniskill.policies.remote.wire", fromlist=["packb"]).packb(
            {"observation": _obs(1, 1)[0], "prompt": "a"}))
        a._ws.close()  # gone before its reply
        b.reset("b", {})
        chunk = b.act(_obs(1, 2)[0])
        assert np.array_equal(chunk, _action(_obs(1, 2)[0]))
        with RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10) as c:
            c.reset("c", {})
            assert c.act(_obs(1, 3)[0]).shape == (HORIZON, 14)
        b.close()
    assert sum(server.batcher.sizes.values()) >= 2


def test_policy_error_reaches_the_clients_of_its_call_and_the_server_goes_on(tmp_path):
    poison = _obs(1, 40)[0]
    policy = CountedPolicy(str(tmp_path / "loads"), fail_on=float(poison.sum()))
    with PolicyServer(policy, host="127.0.0.1", port=0, max_wait_ms=WAIT_FOREVER_MS, log=lambda line: None) as server:
        clients = [RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10) for _ in range(2)]
        obs = [poison, _obs(1, 5)[0]]
        out: list = [None, None]

        def act(i):
            clients[i].reset("p", {})
            try:
                out[i] = clients[i].act(obs[i])
            except RuntimeError as err:
                out[i] = err

        threads = [threading.Thread(target=act, args=(i,)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=30)
        for c in clients:
            c.close()
        assert all(isinstance(o, RuntimeError) and "poison" in str(o) for o in out), out  # one call: both rows
        with RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10) as again:
            again.reset("p", {})
            assert np.array_equal(again.act(obs[1]), _action(obs[1]))


def test_rsb_serve_batches_two_clients_and_stops_on_ctrl_c(tmp_path):
    """`rsb serve` in a subprocess: loads once, serves two batched clients, Ctrl-C prints the batch sizes."""
    loads = tmp_path / "loads"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HELPERS), *sys.path]))
    log = tmp_path / "serve.err"
    with open(log, "w") as err:
        # no `timeout` wrapper: it would pass the SIGINT on to its whole process group, a second Ctrl-C
        proc = subprocess.Popen([sys.executable, "-m", "rsb_maniskill.cli", "serve",
                                 "counted_policies:make_counted", "-a", f"log={loads}", "--host", "127.0.0.1",
                                 "--port", "0", "--max-batch", "8", "--max-wait-ms", "20",
                                 "--parent-pid", str(os.getpid())],  # stops by itself if the test dies
                                stdout=subprocess.PIPE, stderr=err, env=env, text=True)
    try:
        line = proc.stdout.readline()
        m = re.search(rf"{READY} ws://127\.0\.0\.1:(\d+)", line)
        assert m, f"no ready line: {line!r} {log.read_text()}"
        port = int(m.group(1))
        for _ in range(2):
            with RemotePolicy("127.0.0.1", port, mark_episode_start=True, connect_timeout=10,
                              request_timeout=10) as client:
                client.reset_batch(["a", "b"], {})
                chunks = client.act_batch(_obs(2, 0), [0, 1])
                assert [c.tolist() for c in chunks] == [_action(r).tolist() for r in _obs(2, 0)]
        proc.send_signal(subprocess.signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = log.read_text()
    assert "reset_envs" in text and re.search(r"batches formed: 2 policy calls", text), text
    assert loads.read_text().count("\n") == 1


def test_episode_seeds_reach_the_served_resets(tmp_path):
    """The runner's seed= / seeds= travel with the episode start, so a seeded policy acts as in a worker."""
    class Single(CountedSingle):
        seeds: list = []  # on the class: every row (a copy of the policy) adds to it

        def reset(self, instruction, obs, seed=None):
            super().reset(instruction, obs, seed)
            self.seeds.append(seed)

    batched, single = CountedPolicy(str(tmp_path / "a")), Single(str(tmp_path / "b"))
    with PolicyServer(batched, host="127.0.0.1", port=0) as s1, PolicyServer(single, host="127.0.0.1", port=0) as s2:
        with RemotePolicy("127.0.0.1", s1.port, mark_episode_start=True, connect_timeout=10) as client:
            client.reset_batch(["a", "b", "c"], {}, seeds=[30, 31, 32])
            client.act_batch(_obs(2, 0), [0, 2])  # env 1 holds actions: not asked, not reset
        with RemotePolicy("127.0.0.1", s2.port, mark_episode_start=True, connect_timeout=10) as client:
            client.reset("p", {}, seed=7)
            client.act(_obs(1, 0)[0])
    assert batched.seeds == [30, 32] and Single.seeds == [7]


def test_rsb_serve_refuses_a_policy_built_with_the_env():
    from rsb_maniskill.cli import main

    assert main(["serve", "oracle", "--host", "127.0.0.1", "--port", "0"]) == 2


def test_auto_shares_only_a_gpu_model_on_a_gpu_machine():
    from rsb_maniskill.policies.remote.shared import choose

    gpu_model = "counted_policies:make_counted"  # declares heavy and gpu
    assert choose("auto", gpu_model, 4, cuda=True) == ("shared", f"{gpu_model}'s model runs on the GPU: loaded "
                                                                   "once and batched for the 4 workers")
    choice, why = choose("auto", gpu_model, 4, cuda=False)
    assert choice == "worker" and "has none (CUDA)" in why and "benchmarks/results/policy_server.json" in why
    assert choose("auto", gpu_model, 1, cuda=True)[0] == "worker"
    assert choose("auto", "oracle", 4, cuda=True)[0] == "worker"
    choice, why = choose("auto", "rsb_maniskill.baselines.diffusion_policy:make_policy", 4, cuda=True)
    assert choice == "worker" and "runs on the CPU" in why  # its model computes on the CPU: a copy a worker
    assert choose("auto", "policy_fixtures:EnvIdPolicy", 4, cuda=True)[0] == "worker"  # declares nothing
    assert choose("shared", "rsb_maniskill.baselines.diffusion_policy:make_policy", 4)[0] == "shared"
    with pytest.raises(ValueError, match="built with each worker's env"):
        choose("shared", "random", 4)
    with pytest.raises(ValueError, match="ray"):
        choose("shared", "counted_policies:make_counted", 4, local=False)
