"""The openpi-aloha preset: the layout maps on the real agent, and both directions against openpi's
own packages (`openpi-server` 0.1.0's WebsocketPolicyServer, `openpi-client` 0.1.2's client), run
from a separate virtual environment whose server policy checks what openpi's Aloha input transform
(`openpi.policies.aloha_policy.AlohaInputs`) expects."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from venvs import install, make_venv

import rsb_maniskill  # noqa: E402,F401  (registers the envs)
from rsb_maniskill.agents.aloha import to_aloha14  # noqa: E402
from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS  # noqa: E402
from rsb_maniskill.policies.remote.client import RemotePolicy  # noqa: E402
from rsb_maniskill.policies.remote.openpi import (  # noqa: E402
    QPOS_JOINT_NAMES,
    OpenpiAloha,
    aloha14_from_qpos,
    make_preset,
    qpos_from_aloha14,
    resize_with_pad,
)

REPO = Path(__file__).resolve().parents[2]
# The releases checked (pure Python, numpy < 2). openpi-client 0.1.2's action_chunk_broker imports
# typing_extensions without declaring it.
OPENPI = ("openpi-server==0.1.0", "openpi-client==0.1.2", "typing_extensions")
VENV = Path(os.environ.get("RSB_OPENPI_VENV", REPO / ".cache" / "openpi-0.1-venv"))


def _one_env(obs: dict) -> dict:
    return {k: _one_env(v) if isinstance(v, dict) else v[0].cpu().numpy() for k, v in obs.items()}


@pytest.fixture(scope="module")
def moved_env():
    """An RSB env (rgb obs) after a few random steps, so that no joint sits at its rest value."""
    env = gym.make("RSB-Math-4", obs_mode="rgb", **EVAL_ENV_KWARGS)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(6):
        a = np.concatenate([rng.uniform(-1.2, 1.2, 12), rng.uniform(-1, 1, 2)]).astype(np.float32)
        obs, *_ = env.step(a)
    yield env, _one_env(obs)
    env.close()


def test_state_is_the_agents_aloha14_state(moved_env):
    env, obs = moved_env
    agent = env.unwrapped.agent
    assert list(QPOS_JOINT_NAMES) == agent.active_joint_names
    state = aloha14_from_qpos(obs["agent"]["qpos"])
    np.testing.assert_allclose(state, agent.aloha14_state()[0].cpu().numpy(), atol=1e-6)
    assert state.dtype == np.float32 and 0 < state[6] < 1 and 0 < state[13] < 1  # half-open grippers
    q = obs["agent"]["qpos"].copy()
    q[[13, 15]] = q[[12, 14]]  # fingers 8 mimic fingers 7: the inverse gives them the same opening
    np.testing.assert_allclose(qpos_from_aloha14(state), q, atol=1e-6)


def test_request_layout_and_actions_back(moved_env):
    env, obs = moved_env
    req = OpenpiAloha(image_size=224).request(obs, "pick the block")
    assert set(req) == {"images", "state", "prompt"} and req["prompt"] == "pick the block"
    assert set(req["images"]) == {"cam_high", "cam_left_wrist", "cam_right_wrist"}
    for img in req["images"].values():
        assert img.shape == (3, 224, 224) and img.dtype == np.uint8 and img.flags.c_contiguous
    # 240 x 320 letterboxed into 224 x 224: 168 rows of picture, black bands above and below
    high = req["images"]["cam_high"]
    assert high[:, :28].max() == 0 and high[:, -28:].max() == 0 and high[:, 28:196].mean() > 20
    head = obs["sensor_data"]["head_camera"]["rgb"]
    np.testing.assert_array_equal(high.transpose(1, 2, 0), resize_with_pad(head, 224, 224))
    native = OpenpiAloha(image_size=None).request(obs, "")["images"]["cam_left_wrist"]
    np.testing.assert_array_equal(native, obs["sensor_data"]["left_wrist_camera"]["rgb"].transpose(2, 0, 1))
    assert OpenpiAloha(image_size=[96, 128]).request(obs, "")["images"]["cam_high"].shape == (3, 96, 128)

    chunk = np.random.default_rng(1).uniform(-1, 1, (7, 14)).astype(np.float32)
    aloha = to_aloha14(chunk)
    np.testing.assert_allclose(OpenpiAloha().env_actions(aloha), chunk, atol=1e-6)
    padded = np.concatenate([aloha, np.zeros((7, 18), np.float32)], 1)  # openpi models pad to 32 dims
    np.testing.assert_allclose(OpenpiAloha().env_actions(padded), chunk, atol=1e-6)
    with pytest.raises(ValueError, match=r"\(T, 14\)"):
        OpenpiAloha().env_actions(np.zeros((5, 7)))
    with pytest.raises(ValueError, match="missing: right_wrist_camera"):
        OpenpiAloha().request({"agent": obs["agent"], "sensor_data": {k: v for k, v in obs["sensor_data"].items()
                                                                      if k != "right_wrist_camera"}}, "")


def test_bad_preset_arguments(tmp_path, capsys):
    from rsb_maniskill.cli import main

    for args, msg in ((["-a", "preset=openpi-droid"], "unknown preset 'openpi-droid'"),
                      (["-a", "preset=openpi-aloha", "-o", "state"], "use an rgb obs mode"),
                      (["-a", "image_size=224"], "image_size applies to a preset")):
        assert main(["eval", "remote", *args, "--suites", "RSB-Math-4", "-n", "1", "--out", str(tmp_path / "x")]) == 2
        assert msg in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before anything was written
    with pytest.raises(ValueError, match="unknown preset 'openpi-droid'; known: openpi-aloha"):
        make_preset("openpi-droid")
    with pytest.raises(ValueError, match="image_size"):
        make_preset("openpi-aloha", image_size=[224])
    with pytest.raises(ValueError, match="image_size applies to a preset"):
        RemotePolicy("127.0.0.1", 1, image_size=224, connect_timeout=0)
    with pytest.raises(ValueError, match="14 numbers"):
        qpos_from_aloha14(np.zeros(16))
    with pytest.raises(ValueError, match="16 joints"):
        aloha14_from_qpos(np.zeros(14))


def test_server_side_maps_openpi_requests():
    from rsb_maniskill.policies.remote.server import PolicyServer

    class Seen:
        def reset(self, instruction, obs):
            self.instruction = instruction

        def act(self, obs):
            self.obs = obs
            return np.tile(np.r_[obs["agent"]["qpos"][[0, 2, 4, 6, 8, 10, 1, 3, 5, 7, 9, 11]], -1, 1], (4, 1))

        def fork(self):  # served: the env drives this object, so the test reads what it saw
            return self

    def served(request):
        with PolicyServer(policy, host="127.0.0.1", port=0, preset=make_preset("openpi-aloha")) as server:
            return server.respond(server.batcher.open(), request)

    policy, state = Seen(), np.r_[np.arange(6) / 10, 0.25, -np.arange(6) / 10, 1.0].astype(np.float32)
    img = np.zeros((3, 224, 224), np.uint8)
    reply = served({"images": {"cam_high": img, "cam_left_wrist": img}, "state": state, "prompt": "go"})
    assert policy.instruction == "go" and set(policy.obs["sensor_data"]) == {"head_camera", "left_wrist_camera"}
    assert policy.obs["sensor_data"]["head_camera"]["rgb"].shape == (224, 224, 3)
    np.testing.assert_allclose(aloha14_from_qpos(policy.obs["agent"]["qpos"]), state, atol=1e-6)
    # env actions [left 6, right 6, left grip -1, right grip 1] -> Aloha, grippers 0 (closed) and 1
    np.testing.assert_allclose(reply["actions"][0], np.r_[state[:6], 0, state[7:13], 1], atol=1e-6)
    with pytest.raises(ValueError, match="unknown cameras"):
        served({"images": {"cam_low": img}, "state": state})


# ------------------------------------------------------------ against openpi's own packages
def _openpi_python() -> Path:
    """Python of a virtual environment with openpi's server and client (built once, reused)."""
    py = VENV / "bin" / "python"
    check = [str(py), "-c", "import openpi_server, openpi_client.action_chunk_broker"]
    if py.exists() and subprocess.run(check, capture_output=True).returncode == 0:
        return py
    install(make_venv(VENV, sys.executable), *OPENPI, timeout=900)
    return py


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(argv: list[str], tmp_path: Path, name: str, env: dict | None = None) -> subprocess.Popen:
    log = open(tmp_path / f"{name}.log", "w")
    return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tmp_path)


def _wait_healthy(port: int, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    """Until the server answers GET /healthz (openpi's client does not retry a refused connection)."""
    import time
    import urllib.request

    direct = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # never via a proxy
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            with direct.open(f"http://127.0.0.1:{port}/healthz", timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.3)
    raise AssertionError(f"policy server on port {port} not up (exit code {proc.poll()})")


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()


# openpi's Aloha checks, transcribed from src/openpi/policies/aloha_policy.py (AlohaInputs and
# _decode_aloha, openpi commit 15a9616): cameras within EXPECTED_CAMERAS with cam_high present,
# images [channel, height, width], state [14] with the grippers in [0, 1] (0 closed), decoded with
# adapt_to_pi (joint flips, Interbotix gripper map). The policy replies with a chunk that moves the
# left waist (slot 0) to -0.3 and closes the right gripper (slot 13): Aloha layout, absolute.
OPENPI_SERVER = """
import json, sys, threading, os
import numpy as np
from openpi_client import base_policy, image_tools
from openpi_server import WebsocketPolicyServer

EXPECTED_CAMERAS = ("cam_high", "cam_low", "cam_left_wrist", "cam_right_wrist")
port, log_path, size = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
threading.Timer(600, os._exit, (3,)).start()  # never outlive the test

def gripper_to_angular(v):  # aloha_policy._gripper_to_angular
    v = v * (0.05800 - 0.01844) + 0.01844
    v = np.arcsin(np.clip((0.022**2 + v**2 - 0.036**2) / (2 * 0.022 * v), -1.0, 1.0))
    return (v - 0.5476) / (1.6296 - 0.5476)

class AlohaChecker(base_policy.BasePolicy):
    def infer(self, obs):
        assert set(obs) <= {"images", "state", "prompt"}, sorted(obs)
        images, state = obs["images"], obs["state"]
        assert set(images) <= set(EXPECTED_CAMERAS) and "cam_high" in images, sorted(images)
        assert set(images) == {"cam_high", "cam_left_wrist", "cam_right_wrist"}, sorted(images)
        for name, img in images.items():
            assert isinstance(img, np.ndarray) and img.dtype == np.uint8, (name, type(img), img.dtype)
            assert img.shape == (3, size, size), (name, img.shape)  # [channel, height, width]
            assert img.transpose(1, 2, 0).max() > 0, name
        assert isinstance(obs["prompt"], str) and obs["prompt"], obs.get("prompt")
        assert state.shape == (14,) and state.dtype == np.float32 and np.isfinite(state).all(), state
        assert 0.0 <= state[6] <= 1.0 and 0.0 <= state[13] <= 1.0, state[[6, 13]]
        assert np.abs(state[[0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]]).max() < 3.2, state
        decoded = np.array([1, -1, -1, 1, 1, 1, 1, 1, -1, -1, 1, 1, 1, 1]) * state
        decoded[[6, 13]] = gripper_to_angular(decoded[[6, 13]])
        assert np.isfinite(decoded).all(), decoded
        chunk = np.tile(state, (50, 1))
        chunk[:, 0], chunk[:, 13] = -0.3, 0.0
        with open(log_path, "a") as f:
            f.write(json.dumps({"state": state.tolist(), "prompt": obs["prompt"]}) + "\\n")
        return {"actions": chunk}

WebsocketPolicyServer(AlohaChecker(), host="127.0.0.1", port=port, metadata={"policy": "aloha-checker"}).serve_forever()
"""


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_rsb_eval_remote_against_openpi_server(tmp_path):
    from rsb_maniskill.cli import main
    from rsb_maniskill.evaluation.store import read_records

    py = _openpi_python()
    (tmp_path / "server.py").write_text(OPENPI_SERVER)
    port, log = _free_port(), tmp_path / "requests.jsonl"
    server = _start([str(py), "server.py", str(port), str(log), "224"], tmp_path, "server",
                    env={**os.environ, "PYTHONPATH": ""})
    try:
        rc = main(["eval", "remote", "-a", "host=127.0.0.1", "-a", f"port={port}", "-a", "preset=openpi-aloha",
                   "-a", "connect_timeout=60", "--name", "pi0-check", "--suites", "RSB-Math-4", "-n", "1",
                   "--max-steps", "25", "--out", str(tmp_path / "out"), "-q"])
    finally:
        _stop(server)
    assert rc == 0, (tmp_path / "server.log").read_text()[-3000:]
    (record,) = read_records(tmp_path / "out" / "episodes.jsonl")
    requests = [json.loads(line) for line in log.read_text().splitlines()]
    assert record["steps"] == 25 and len(requests) == 3  # 10 actions executed per chunk by default
    assert {r["prompt"] for r in requests} == {record["instruction"]}
    first, later = np.array(requests[0]["state"]), np.array(requests[-1]["state"])
    # the rest pose in the Aloha layout: left arm, open gripper, right arm, open gripper
    np.testing.assert_allclose(first, [-0.6, 0.6, 0.8, -1.2, 0, 0, 1, 0.6, 0.6, 0.8, -1.2, 0, 0, 1], atol=0.02)
    # the reply's slot 0 moved the left waist and slot 13 closed the right gripper, nothing else
    assert later[0] > -0.45 and later[13] < 0.5 and later[6] > 0.95
    np.testing.assert_allclose(later[[1, 2, 3, 7, 8, 9, 10]], first[[1, 2, 3, 7, 8, 9, 10]], atol=0.05)
    assert (tmp_path / "out" / "report.html").exists()


# An openpi client as openpi's ALOHA examples write one: images resized with openpi's own
# resize_with_pad to 224, CHW uint8, the 14-number state, an ActionChunkBroker executing 5 actions.
OPENPI_CLIENT = """
import json, sys
import numpy as np
from openpi_client import action_chunk_broker, image_tools, websocket_client_policy

port, frame_path = int(sys.argv[1]), sys.argv[2]
frame = np.load(frame_path)  # (240, 320, 3) uint8
img = image_tools.convert_to_uint8(image_tools.resize_with_pad(frame, 224, 224)).transpose(2, 0, 1)
state = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.25, -0.1, -0.2, -0.3, -0.4, -0.5, -0.6, 1.0], np.float32)
client = websocket_client_policy.WebsocketClientPolicy(host="127.0.0.1", port=port)
broker = action_chunk_broker.ActionChunkBroker(client, action_horizon=5)
obs = {"images": {"cam_high": img, "cam_left_wrist": img, "cam_right_wrist": img}, "state": state,
       "prompt": "put the answer in the zone"}
steps = [broker.infer(obs)["actions"].tolist() for _ in range(7)]
np.save(frame_path + ".resized.npy", img.transpose(1, 2, 0))
print(json.dumps({"metadata": client.get_server_metadata(), "steps": steps}))
"""

RSB_POLICY = """
import numpy as np

class EnvLayoutEcho:
    '''Sees the env's nested obs; returns env-layout actions: arms hold the state, grippers close.'''
    def __init__(self):
        self.calls = 0

    def reset(self, instruction, obs):
        assert instruction == "put the answer in the zone", instruction

    def act(self, obs):
        assert obs["sensor_data"]["head_camera"]["rgb"].shape == (224, 224, 3), obs["sensor_data"].keys()
        q = obs["agent"]["qpos"]
        assert q.shape == (16,), q.shape
        self.calls += 1
        arms = q[[0, 2, 4, 6, 8, 10, 1, 3, 5, 7, 9, 11]]
        return np.tile(np.r_[arms, -1.0, -1.0, ], (8, 1)) + 0.01 * self.calls * np.r_[np.ones(12), 0, 0]

def make():
    return EnvLayoutEcho()
"""


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_openpi_client_against_rsb_serve(tmp_path, moved_env):
    py = _openpi_python()
    frame = moved_env[1]["sensor_data"]["head_camera"]["rgb"]
    np.save(tmp_path / "frame.npy", frame)
    (tmp_path / "client.py").write_text(OPENPI_CLIENT)
    (tmp_path / "rsb_echo.py").write_text(RSB_POLICY)
    port = _free_port()
    server = _start([sys.executable, "-m", "rsb_maniskill.policies.remote.server", "rsb_echo:make", "--preset",
                     "openpi-aloha", "--host", "127.0.0.1", "--port", str(port)], tmp_path, "serve",
                    env={**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])})
    try:
        _wait_healthy(port, server)
        res = subprocess.run([str(py), "client.py", str(port), str(tmp_path / "frame.npy")], cwd=tmp_path,
                             capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": ""})
    finally:
        _stop(server)
    assert res.returncode == 0, res.stderr[-3000:] + (tmp_path / "serve.log").read_text()[-3000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    steps = np.array(got["steps"])
    assert steps.shape == (7, 14)
    state = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.25, -0.1, -0.2, -0.3, -0.4, -0.5, -0.6, 1.0])
    # Aloha layout back: arms where the state was (+0.01 per call), grippers commanded closed (0)
    first = np.r_[state[:6] + 0.01, 0, state[7:13] + 0.01, 0]
    np.testing.assert_allclose(steps[:5], np.tile(first, (5, 1)), atol=1e-5)
    np.testing.assert_allclose(steps[5][[0, 6, 7, 13]], [0.12, 0, -0.08, 0], atol=1e-5)  # second chunk
    # our letterbox is openpi_client's resize_with_pad, pixel for pixel
    np.testing.assert_array_equal(resize_with_pad(frame, 224, 224), np.load(tmp_path / "frame.npy.resized.npy"))
