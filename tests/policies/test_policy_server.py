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

from rsb_maniskill.policies.remote.batching import Batcher, Request, row_copy  # noqa: E402
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


def test_a_row_that_raises_fails_its_request_only(tmp_path):
    poison = _obs(1, 40)
    policy = CountedPolicy(str(tmp_path / "loads"), fail_on=float(poison.sum()))
    batcher = Batcher(policy, max_batch=64, max_wait_ms=WAIT_FOREVER_MS)
    conns = [batcher.open() for _ in range(3)]
    obs = [_obs(2, 0), np.concatenate([_obs(1, 7), poison]), _obs(1, 80)]
    out = _submit_all(batcher, [Request(c, list(range(len(o))), ["p"] * len(o), True, o) for c, o in zip(conns, obs)])
    batcher.stop()
    assert isinstance(out[1], RuntimeError) and "poison" in str(out[1])
    for i in (0, 2):
        chunks, _ = out[i]
        assert [c.tolist() for c in chunks] == [_action(r).tolist() for r in obs[i]]


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
    assert "one row at a time" in batcher.describe()
    assert (tmp_path / "loads").read_text().count("\n") == 1  # the copies load nothing


def test_row_copy_shares_the_model_and_copies_the_episode_state():
    import torch

    class P:
        def __init__(self):
            self.net = torch.nn.Linear(2, 2)
            self.history = [1.0]
            self.gen = torch.Generator()

    p = P()
    q = row_copy(p)
    assert q.net is p.net and q.gen is p.gen and q.history == p.history and q.history is not p.history


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


def test_policy_error_reaches_only_its_client_over_the_wire(tmp_path):
    poison = _obs(1, 40)[0]
    policy = CountedPolicy(str(tmp_path / "loads"), fail_on=float(poison.sum()))
    with PolicyServer(policy, host="127.0.0.1", port=0, max_wait_ms=WAIT_FOREVER_MS) as server:
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
    assert isinstance(out[0], RuntimeError) and "poison" in str(out[0])
    assert np.array_equal(out[1], _action(obs[1]))


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
    batched, single = CountedPolicy(str(tmp_path / "a")), CountedSingle(str(tmp_path / "b"))
    with PolicyServer(batched, host="127.0.0.1", port=0) as s1, PolicyServer(single, host="127.0.0.1", port=0) as s2:
        with RemotePolicy("127.0.0.1", s1.port, mark_episode_start=True, connect_timeout=10) as client:
            client.reset_batch(["a", "b", "c"], {}, seeds=[30, 31, 32])
            client.act_batch(_obs(2, 0), [0, 2])  # env 1 holds actions: not asked, not reset
        with RemotePolicy("127.0.0.1", s2.port, mark_episode_start=True, connect_timeout=10) as client:
            client.reset("p", {}, seed=7)
            client.act(_obs(1, 0)[0])
    assert batched.seeds == [30, 32] and single.seed == 7


def test_rsb_serve_refuses_a_policy_built_with_the_env():
    from rsb_maniskill.cli import main

    assert main(["serve", "oracle", "--host", "127.0.0.1", "--port", "0"]) == 2


def test_auto_shares_heavy_policies_only():
    from rsb_maniskill.policies.remote.shared import choose

    assert choose("auto", "counted_policies:make_counted", 4)[0] == "shared"
    assert choose("auto", "counted_policies:make_counted", 1)[0] == "worker"
    assert choose("auto", "oracle", 4)[0] == "worker"
    assert choose("auto", "rsb_maniskill.baselines.diffusion_policy:make_policy", 4)[0] == "shared"
    assert choose("auto", "policy_fixtures:EnvIdPolicy", 4)[0] == "worker"  # declares nothing
    with pytest.raises(ValueError, match="built with each worker's env"):
        choose("shared", "random", 4)
    with pytest.raises(ValueError, match="ray"):
        choose("shared", "counted_policies:make_counted", 4, local=False)
