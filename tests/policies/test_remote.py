"""openpi wire protocol: msgpack-numpy codec, and RemotePolicy against a loopback PolicyServer."""
from __future__ import annotations

import msgpack
import numpy as np
import pytest

from rsb_maniskill.policies.remote.client import RemotePolicy  # noqa: E402
from rsb_maniskill.policies.remote.server import PolicyServer  # noqa: E402
from rsb_maniskill.policies.remote.wire import flatten_obs, packb, unflatten_obs, unpackb  # noqa: E402

pytestmark = pytest.mark.timeout(60)

T, D = 5, 14


def sample_obs(step=0):
    rng = np.random.default_rng(step)
    return {
        "agent": {"qpos": rng.standard_normal(14).astype(np.float32), "qvel": rng.standard_normal(14)},
        "sensor_data": {"head": {"rgb": rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)}},
        "extra": {"zone": np.array([0.17, 0.0, 0.0], dtype=np.float32), "ok": np.array([True, False])},
        "step": np.int64(step),
    }


# ---------------------------------------------------------------- codec
@pytest.mark.parametrize("value", [
    np.arange(6, dtype=np.float32).reshape(2, 3),
    np.zeros((2, 0, 3), dtype=np.uint8),
    np.array(1.5),
    np.array([[True], [False]]), np.array([1, 2], dtype=">u4"), np.array([1, -2], dtype=np.float16),
    np.array([np.nan, np.inf]),
    np.arange(12, dtype=np.int16).reshape(3, 4).T,  # non-contiguous
    np.float32(2.5), np.int64(-3), np.bool_(True),
])
def test_codec_roundtrip(value):
    back = unpackb(packb({"x": value, "nested": [value, {"y": value}]}))
    for got in (back["x"], back["nested"][0], back["nested"][1]["y"]):
        assert type(got) is type(value) and got.dtype == value.dtype and np.shape(got) == np.shape(value)
        assert np.array_equal(got, value, equal_nan=value.dtype.kind == "f")


def test_codec_bytes_are_openpis():
    # openpi_client.msgpack_numpy tags arrays with bytes keys, raw bytes, dtype.str and shape
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    reference = msgpack.packb({
        "actions": {b"__ndarray__": True, b"data": a.tobytes(), b"dtype": "<f4", b"shape": [2, 3]},
        "s": {b"__npgeneric__": True, b"data": 7, b"dtype": "<i8"},
    })
    assert packb({"actions": a, "s": np.int64(7)}) == reference


@pytest.mark.parametrize("value", [np.array([object()]), np.array(["ab", "c"]), np.array([1j]),
                                   np.zeros(2, dtype=[("a", "<f4")]), np.complex64(1j)])
def test_codec_sends_only_the_dtypes_a_receiver_takes(value):
    with pytest.raises(TypeError, match="only bool, int, uint and float"):
        packb({"x": value})


def test_flatten_unflatten():
    obs = sample_obs()
    flat = flatten_obs(obs)
    assert set(flat) == {"observation/agent/qpos", "observation/agent/qvel", "observation/sensor_data/head/rgb",
                         "observation/extra/zone", "observation/extra/ok", "observation/step"}
    back = unflatten_obs(flat | {"prompt": "p"})
    assert back["prompt"] == "p" and back["sensor_data"]["head"]["rgb"] is obs["sensor_data"]["head"]["rgb"]


# ---------------------------------------------------------------- loopback
class EchoPolicy:
    """Records what the server side received; the chunk encodes the call count."""

    def __init__(self):
        self.resets, self.seen, self.calls = [], [], 0

    def reset(self, instruction, obs):
        self.resets.append(instruction)

    def act(self, obs):
        self.seen.append(obs)
        self.calls += 1
        return np.full((T, D), self.calls, dtype=np.float32) + np.arange(T, dtype=np.float32)[:, None]

    def fork(self):  # served: every env drives this one recorder (one client at a time here), so a test reads it
        return self


def _assert_same_tree(sent, got):
    assert set(sent) == set(got)
    for k, v in sent.items():
        if isinstance(v, dict):
            _assert_same_tree(v, got[k])
        else:
            assert got[k].dtype == v.dtype and got[k].shape == np.shape(v) and np.array_equal(got[k], v)


def test_remote_policy_against_loopback_server():
    policy = EchoPolicy()
    with PolicyServer(policy, host="127.0.0.1", port=0, metadata={"action_dim": D}) as server:
        assert server.port > 0
        with RemotePolicy("127.0.0.1", server.port, mark_episode_start=True, connect_timeout=10,
                          request_timeout=10) as client:
            assert client.server_metadata == {"action_dim": D}
            prompt = "put the answer to 2+2 in the zone"
            for _episode in range(2):
                client.reset(prompt, sample_obs())
                for step in range(3):
                    obs = sample_obs(step)
                    chunk = client.act(obs)
                    assert chunk.shape == (T, D) and chunk.dtype == np.float32
                    assert chunk[0, 0] == policy.calls and chunk[T - 1, 0] == policy.calls + T - 1
                    _assert_same_tree(obs, policy.seen[-1])
            # same prompt twice: the episode-start mark, not a prompt change, caused the second reset
            assert policy.resets == ["put the answer to 2+2 in the zone"] * 2
            assert policy.calls == 6


def test_action_horizon_and_plain_openpi_server_object():
    class OpenpiStyle:  # an object with openpi's infer(): sees the raw flat request
        def __init__(self):
            self.requests = []

        def infer(self, request):
            self.requests.append(request)
            return {"actions": np.ones((10, D), dtype=np.float64)}

    served = OpenpiStyle()
    with PolicyServer(served, host="127.0.0.1", port=0) as server:
        with RemotePolicy("127.0.0.1", server.port, action_horizon=4, connect_timeout=10, request_timeout=10) as client:
            client.reset("blank test", {})
            chunk = client.act(sample_obs())
            assert chunk.shape == (4, D) and chunk.dtype == np.float64
            reply = client.infer({"prompt": "raw"})
            assert "server_timing" in reply and reply["actions"].shape == (10, D)
    req = served.requests[0]
    # episode_start is off by default: openpi servers do not expect the key
    assert req["prompt"] == "blank test" and "episode_start" not in req
    assert req["observation/sensor_data/head/rgb"].dtype == np.uint8


def test_server_error_reaches_the_client():
    class Broken:
        def reset(self, instruction, obs):
            pass

        def act(self, obs):
            raise RuntimeError("model exploded")

    with PolicyServer(Broken(), host="127.0.0.1", port=0) as server:
        client = RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10)
        client.reset("x", {})
        with pytest.raises(RuntimeError, match="model exploded"):
            client.act(sample_obs())
        client.close()


def test_no_server_fails_in_bounded_time():
    import socket

    with socket.socket() as s:  # a port with nobody listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ConnectionError, match="no policy server"):
        RemotePolicy("127.0.0.1", port, connect_timeout=1.0)


def test_server_resets_on_prompt_change_and_flat_state_obs():
    policy = EchoPolicy()
    with PolicyServer(policy, host="127.0.0.1", port=0) as server:
        conn = server.batcher.open()
        for prompt in ("a", "a", "b", "b", "a"):
            reply = server.respond(conn, flatten_obs(sample_obs()) | {"prompt": prompt})
            assert reply["actions"].shape == (T, D)
    assert policy.resets == ["a", "b", "a"]
    state = np.arange(5, dtype=np.float32)  # obs_mode="state" gives one flat array
    assert np.array_equal(flatten_obs(state)["observation"], state)


# ---------------------------------------------------------------- batched requests (--num-envs)
def _batched_run(client, num_envs=3):
    from rsb_maniskill.evaluation.runner import EpisodeSettings, batched_loop, episode_loop

    from fake_envs import SEEDS, SUITE, FakeBatchedEnv, FakeRSBEnv, ScriptedPolicy

    settings = EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="p")
    single, batched = [], []
    episode_loop(FakeRSBEnv(), ScriptedPolicy(), settings, SEEDS, single.append)
    env = FakeBatchedEnv(num_envs)
    batched_loop(env, client, settings, SEEDS, batched.append)
    strip = lambda rs: [{k: v for k, v in r.items() if k != "wall_s"} for r in rs]  # noqa: E731
    assert sorted(strip(batched), key=lambda r: r["seed"]) == strip(single)
    return env


def test_batched_requests_one_per_step_for_all_envs():
    from policy_fixtures import EnvIdPolicy

    policy = EnvIdPolicy()
    with PolicyServer(policy, host="127.0.0.1", port=0) as server:
        with RemotePolicy("127.0.0.1", server.port, mark_episode_start=True, connect_timeout=10,
                          request_timeout=10) as client:
            env = _batched_run(client)
    first = env.actions[0][:, 0].numpy()
    assert np.allclose(first, [0.0, 0.1, 0.2])  # row i of the reply went to env i
    # 8 seeds in waves of 3, 3, 2: one request per chunk step, not one per env
    assert policy.resets == 3 and policy.calls < len(env.actions) and policy.calls >= len(env.actions) / 3


def test_batch_false_sends_one_request_per_env():
    from policy_fixtures import EnvIdPolicy

    policy = EnvIdPolicy()
    with PolicyServer(policy, host="127.0.0.1", port=0) as server:
        with RemotePolicy("127.0.0.1", server.port, batch=False, connect_timeout=10, request_timeout=10) as client:
            env = _batched_run(client)
    assert np.allclose(env.actions[0][:, 0].numpy(), 0.0)  # the single form answered
    assert policy.calls > len(env.actions) / 3


def test_batched_request_to_a_single_env_policy_is_served_one_row_at_a_time():
    class OwnRows(EchoPolicy):
        fork = None  # each env a deep copy of the policy as built

    policy = OwnRows()
    with PolicyServer(policy, host="127.0.0.1", port=0) as server:
        with RemotePolicy("127.0.0.1", server.port, connect_timeout=10, request_timeout=10) as client:
            client.reset_batch(["a", "b"], {})
            chunks = client.act_batch({"agent": {"qpos": np.zeros((2, 14), np.float32)}}, [0, 1])
    assert [c.shape for c in chunks] == [(T, D), (T, D)]
    # each row a copy with its own episode state (its own call count: 1 each); the policy as built is never driven
    assert [c[0, 0] for c in chunks] == [1, 1] and policy.resets == [] and policy.calls == 0
    assert server.batcher.sizes == {2: 1}  # both rows in one batch


def test_batched_requests_to_a_server_in_another_process(tmp_path):
    """`python -m rsb_maniskill.policies.remote.server` in a subprocess (127.0.0.1, stops by itself)."""
    import os
    import re
    import subprocess
    import sys
    import time
    from pathlib import Path

    from policy_fixtures import EnvIdPolicy  # noqa: F401  (importable here, so in the server too)

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[1] / "helpers"), *sys.path]))
    log = tmp_path / "server.log"
    with open(log, "w") as err:
        proc = subprocess.Popen(["timeout", "60", sys.executable, "-m", "rsb_maniskill.policies.remote.server",
                                 "policy_fixtures:EnvIdPolicy", "--host", "127.0.0.1", "--port", "0"],
                                stdout=err, stderr=err, env=env)  # the ready line (stdout) names the port
    try:
        deadline, port = time.monotonic() + 40, None
        while port is None and time.monotonic() < deadline and proc.poll() is None:
            m = re.search(r"ws://127\.0\.0\.1:(\d+)", log.read_text())
            port = int(m.group(1)) if m else time.sleep(0.1)
        assert port, f"server did not start: {log.read_text()}"
        with RemotePolicy("127.0.0.1", port, mark_episode_start=True, connect_timeout=10,
                          request_timeout=10) as client:
            env_ = _batched_run(client, num_envs=4)
        assert np.allclose(env_.actions[0][:, 0].numpy(), [0.0, 0.1, 0.2, 0.3])
    finally:
        proc.terminate()
        proc.wait(timeout=10)
