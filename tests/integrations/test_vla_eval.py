"""vla-eval: RSB's layout on its wire, `rsb eval remote -a protocol=vla-eval` against vla-eval's own model
server (its PredictModelServer, serve loop, message codec and PNG images), RSB as a vla-eval benchmark
(its orchestrator, `vla_eval.evaluate` and `vla-eval run --no-docker`), and `rsb report` on its results."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from vla_eval.api import serve_background
from vla_eval.model_servers.openvla import OpenVLAModelServer
from vla_eval.model_servers.robodojo_pi05 import RoboDojoPi05ModelServer
from vla_eval.results.collector import ResultCollector
from vla_eval.specs import STATE_EEF_POS_AA_GRIP, DimSpec

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE, eval_seeds
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.integrations.vla_eval import RSBBenchmark
from rsb_maniskill.policies.interface import obs_rows
from rsb_maniskill.policies.remote import remote_policy
from rsb_maniskill.policies.remote.openpi import aloha14_from_qpos
from rsb_maniskill.policies.remote.vla_eval import VlaEvalPolicy
from rsb_maniskill.policies.remote.vla_eval_layout import PRESETS, SpecMismatch, VlaEvalLayout, make_layout
from rsb_maniskill.reporting.vla_eval_results import NotRSBResults, records_from_results
from rsb_maniskill.robot import QPOS_JOINT_NAMES, from_aloha14

from vla_eval_servers import CountingServer, OracleServer, RandomServer

pytestmark = pytest.mark.timeout(120)
REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples" / "vla_eval"
SUITE = "RSB-Math-4"
CAMS = ("head", "left_wrist", "right_wrist")


def fake_obs(seed: int = 0, size: tuple[int, int] = (24, 32)) -> dict:
    rng = np.random.default_rng(seed)
    return {"agent": {"qpos": rng.uniform(-1, 1, len(QPOS_JOINT_NAMES)).astype(np.float32) * 0.04},
            "sensor_data": {f"{c}_camera": {"rgb": rng.integers(0, 256, (*size, 3), dtype=np.uint8)} for c in CAMS}}


# ---------------------------------------------------------------- layout
@pytest.mark.parametrize("options", [{}, {"gripper": "closed"}, {"joints": "delta"},
                                     {"gripper": "closed", "joints": "delta", "cameras": "robotwin"}])
def test_layout_actions_round_trip_and_polarity(options):
    layout = make_layout(**options)
    rng = np.random.default_rng(1)
    env = np.concatenate([rng.uniform(-1, 1, (4, 12)), rng.uniform(-1, 1, (4, 2))], axis=1).astype(np.float32)
    state = layout.state(fake_obs()["agent"]["qpos"])
    wire = layout.wire_actions(env, state)
    np.testing.assert_allclose(layout.env_actions(wire, state), env, atol=1e-6)
    plain = aloha14_from_qpos(fake_obs()["agent"]["qpos"])
    if layout.gripper == "closed":  # 1 = closed: the env's -1 (closed) is 1 on the wire, the state flipped
        np.testing.assert_allclose(wire[:, [6, 13]], (1 - env[:, 12:]) / 2, atol=1e-6)
        np.testing.assert_allclose(state[[6, 13]], 1 - plain[[6, 13]])
    else:
        np.testing.assert_allclose(wire[:, [6, 13]], (env[:, 12:] + 1) / 2, atol=1e-6)
        np.testing.assert_allclose(state, plain)
    if layout.joints == "delta":  # arms relative to the state, grippers absolute
        np.testing.assert_allclose(wire[:, :6], env[:, :6] - state[:6], atol=1e-6)


def test_layout_observation_keys_per_preset():
    obs = fake_obs()
    lerobot = PRESETS["lerobot"].observation(obs, "pick")
    assert sorted(lerobot) == ["images", "state", "task_description"] and lerobot["task_description"] == "pick"
    assert sorted(lerobot["images"]) == ["cam_high", "cam_left_wrist", "cam_right_wrist"]
    np.testing.assert_array_equal(lerobot["images"]["cam_left_wrist"], obs["sensor_data"]["left_wrist_camera"]["rgb"])
    robotwin = PRESETS["robotwin"].observation(obs, "pick", images=False)
    assert sorted(robotwin) == ["joint_state", "task_description"]
    assert sorted(PRESETS["robotwin"].observation(obs, "")["images"]) == ["head_camera", "left_camera", "right_camera"]
    assert "state" not in make_layout(state_key="none").observation(obs, "")
    with pytest.raises(ValueError, match="lacks the rgb image of right_wrist"):
        PRESETS["lerobot"].observation({**obs, "sensor_data": {k: v for k, v in obs["sensor_data"].items()
                                                               if "right" not in k}}, "")
    for bad, msg in (({"gripper": "shut"}, "gripper must be one of open, closed"),
                     ({"joints": "delta", "state_key": "none"}, "joints=delta adds the state back"),
                     ({"camera": "rsb"}, "unknown vla-eval layout options"), ({"preset": "droid"}, "unknown")):
        with pytest.raises(ValueError, match=msg):
            make_layout(**bad)
    with pytest.raises(ValueError, match=r"replied actions of shape \(3, 7\)"):
        VlaEvalLayout().env_actions(np.zeros((3, 7)))


def _info(server) -> dict:
    """The HELLO payload a server sends (what vla-eval's serve loop puts in it)."""
    return {"model_server": type(server).__name__,
            "action_spec": {k: v.to_dict() for k, v in server.get_action_spec().items()},
            "observation_spec": {k: v.to_dict() for k, v in server.get_observation_spec().items()}}


def test_server_spec_check_names_both_sides():
    from rsb_maniskill.policies.remote.vla_eval_layout import check_server_spec

    raw = CountingServer()
    check_server_spec(_info(raw), PRESETS["lerobot"])  # the LeRobot bridge's "raw": the checkpoint decides
    # RoboDojo's pi0.5 server: 14 absolute joint positions with grippers, RSB's own layout
    dojo = CountingServer(action_spec=RoboDojoPi05ModelServer.get_action_spec(None))
    check_server_spec(_info(dojo), PRESETS["robotwin"])
    with pytest.raises(SpecMismatch) as err:
        check_server_spec(_info(dojo), make_layout(joints="delta"))
    assert "14xabsolute_joint_positions_with_grippers" in str(err.value)
    openvla = CountingServer(action_spec=OpenVLAModelServer.get_action_spec(None))  # end-effector deltas
    with pytest.raises(SpecMismatch) as err:
        check_server_spec(_info(openvla), PRESETS["lerobot"])
    line = str(err.value)
    assert "\n" not in line and "3xdelta_xyz + rotation 3xaxis_angle + gripper 1xbinary_close_positive" in line
    assert "RSB (cameras=rsb, state_key=state, gripper=open, joints=absolute) takes actions 14x" in line
    eef = CountingServer(observation_spec={"state": STATE_EEF_POS_AA_GRIP})
    with pytest.raises(SpecMismatch, match="reads state state 8xeef_pos3_axisangle3_gripper2; RSB .* sends state 14x"):
        check_server_spec(_info(eef), PRESETS["lerobot"])
    with pytest.raises(SpecMismatch, match="sends no state"):
        check_server_spec(_info(CountingServer(observation_spec={"state": DimSpec("state", 0, "raw")})),
                          make_layout(state_key="none"))


# ---------------------------------------------------------------- the client against vla-eval's server
def test_client_draws_a_chunking_servers_buffer_with_one_rendered_observation():
    server = CountingServer(horizon=5, chunk_size=5)
    obs = fake_obs()
    with serve_background(server) as handle, remote_policy("vla-eval", host=handle.url, port=None,
                                                           chunk_size=5, connect_timeout=10) as client:
        assert client.server_info["model_server"] == "CountingServer" and client.server_info["protocol_version"] == 1
        client.reset("put the answer in the zone", obs)
        first, second = client.act(obs), client.act(fake_obs(1))
        client.reset("again", obs)
        third = client.act(obs)
    # one predict() per chunk, on the rendered observation; the 4 buffered steps drew no predict()
    assert len(server.seen) == 3
    got = server.seen[0]
    assert got["task_description"] == "put the answer in the zone" and server.seen[2]["task_description"] == "again"
    for c in CAMS:  # vla-eval's PNG codec is lossless: the pixels arrive as rendered
        key = {"head": "cam_high", "left_wrist": "cam_left_wrist", "right_wrist": "cam_right_wrist"}[c]
        np.testing.assert_array_equal(got["images"][key], obs["sensor_data"][f"{c}_camera"]["rgb"])
    np.testing.assert_allclose(got["state"], aloha14_from_qpos(obs["agent"]["qpos"]))
    wire = 0.01 * np.arange(3)[:, None] + 0.001 * np.arange(5)[None, :]  # call c, step t
    for chunk, c in ((first, 0), (second, 1), (third, 2)):
        assert chunk.shape == (5, 14)
        np.testing.assert_allclose(chunk, from_aloha14(np.repeat(wire[c][:, None], 14, axis=1)), atol=1e-6)


def test_whole_chunk_replies_text_and_errors():
    server = CountingServer(horizon=6, text="C")  # no chunk_size: the server replies its whole chunk
    with serve_background(server) as handle:
        with VlaEvalPolicy(handle.url, None, chunk_size=4, connect_timeout=10) as client:
            client.reset("pick", fake_obs())
            reply = client.act(fake_obs())
            assert sorted(reply) == ["actions", "text"] and reply["text"] == "C"  # the text channel's form
            assert reply["actions"].shape == (4, 14)  # cut to chunk_size
            client.reset("fail now", fake_obs())
            with pytest.raises(RuntimeError, match="observation_failed: ValueError: told to fail"):
                client.act(fake_obs())
            client.reset("pick", fake_obs())  # the session stays usable after an error
            assert client.act(fake_obs())["actions"].shape == (4, 14)
        with VlaEvalPolicy(handle.url, None, connect_timeout=10) as client:
            client.reset("pick", fake_obs())
            assert client.act(fake_obs())["actions"].shape == (6, 14)


def test_batched_form_one_session_per_env():
    server = CountingServer(horizon=3, chunk_size=3)
    obs = {"agent": {"qpos": np.stack([fake_obs(i)["agent"]["qpos"] for i in range(3)])},
           "sensor_data": {f"{c}_camera": {"rgb": np.stack([fake_obs(i)["sensor_data"][f"{c}_camera"]["rgb"]
                                                            for i in range(3)])} for c in CAMS}}
    with serve_background(server) as handle, VlaEvalPolicy(handle.url, None, chunk_size=3, connect_timeout=10) as p:
        p.reset_batch(["a", "b", "c"], obs)
        assert len(p.sessions) == 3
        chunks = p.act_batch(obs_rows(obs, [0, 2]), [0, 2])
    assert len(chunks) == 2 and all(c.shape == (3, 14) for c in chunks)
    assert sorted(o["task_description"] for o in server.seen) == ["a", "c"]
    np.testing.assert_array_equal(next(o for o in server.seen if o["task_description"] == "c")["images"]["cam_high"],
                                  obs["sensor_data"]["head_camera"]["rgb"][2])


def test_rsb_eval_refuses_a_mismatched_or_missing_server(tmp_path, capsys):
    openvla = CountingServer(action_spec=OpenVLAModelServer.get_action_spec(None))
    with serve_background(openvla) as handle:
        rc = main(["eval", "remote", "-a", "protocol=vla-eval", "-a", f"host={handle.url}", "-a", "port=null",
                   "--suites", SUITE, "-n", "1", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "vla-eval server CountingServer declares actions position" in err[0]
    assert "RSB (cameras=rsb" in err[0] and not (tmp_path / "x").exists()
    for args, msg in ((["-a", "port=1", "-a", "connect_timeout=0.5"], "no policy server at ws://127.0.0.1:1"),
                      (["-a", "preset=openpi-aloha"], "unknown vla-eval preset 'openpi-aloha'"),
                      (["-a", "action_horizon=5"], "-a action_horizon: not an option of protocol=vla-eval"),
                      (["-o", "state"], "not obs mode 'state'")):
        assert main(["eval", "remote", "-a", "protocol=vla-eval", *args, "--suites", SUITE, "-n", "1",
                     "--out", str(tmp_path / "x")]) == 2
        assert msg in capsys.readouterr().err
    assert main(["eval", "remote", "-a", "protocol=grpc", "--suites", SUITE, "--out", str(tmp_path / "x")]) == 2
    assert "unknown protocol; known: openpi, vla-eval" in capsys.readouterr().err


# ---------------------------------------------------------------- RSB as a vla-eval benchmark
def test_benchmark_tasks_metrics_and_bad_params():
    bench = RSBBenchmark()
    assert [t["suite"] for t in bench.get_tasks()] == ["RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4",
                                                       "RSB-HardMath-10", "RSB-General-4", "RSB-General-10"]
    assert set(bench.get_metric_keys()) == {"gsr", "tsr", "success", "grasped_any", "grasped_correct",
                                            "placed_correct", "placed_wrong"}
    assert bench.get_metadata()["max_steps"] == 300 and bench.get_metadata()["max_episodes_per_task"] == 500
    assert bench.get_action_spec()["actions"].dims == 14 and "image" in bench.get_observation_spec()
    assert "image" not in RSBBenchmark(SUITE, obs_mode="state_dict").get_observation_spec()
    for kwargs, msg in (({"suites": "RSB-Math-5"}, "RSB-Math-5"), ({"instruction_mode": "silent"}, "instruction_mode"),
                        ({"obs_mode": "state"}, "obs_mode"), ({"render_every": 0}, "render_every must be >= 1")):
        with pytest.raises(ValueError, match=msg):
            RSBBenchmark(**kwargs)
    with pytest.raises(ValueError, match="episodes_per_task must not exceed it"):
        RSBBenchmark(SUITE, episodes=2).reset({"suite": SUITE, "episode_idx": 2})


@pytest.mark.parametrize("config", sorted(p.name for p in EXAMPLES.glob("rsb_*.yaml")))
def test_example_configs_load_in_vla_eval(config):
    """vla-eval's own loader and config classes read them; RSBBenchmark takes every entry's params."""
    from vla_eval.cli.config_loader import load_config
    from vla_eval.config import EvalConfig

    entries = [EvalConfig.from_dict(e) for e in load_config(str(EXAMPLES / config))["benchmarks"]]
    for entry in entries:
        bench = RSBBenchmark(**entry.params)
        assert len(bench.get_tasks()) == 6 and entry.episodes_per_task == bench.episodes == 500
    assert len({e.resolved_name() for e in entries}) == len(entries)


def test_benchmark_episodes_are_the_protocols(tmp_path):
    """Episode i is protocol episode i; shuffled instructions are `rsb eval`'s; the record is `rsb eval`'s."""
    import anyio

    from rsb_maniskill.evaluation.protocol import shuffled_instruction

    bench = RSBBenchmark(SUITE, episodes=3, obs_mode="state_dict", instruction_mode="shuffled", max_steps=3)
    try:
        told = []
        for i in range(3):
            anyio.run(bench.start_episode, {"name": SUITE, "suite": SUITE, "episode_idx": i})
            obs = anyio.run(bench.get_observation)
            assert sorted(obs) == ["state", "task_description"]  # state_dict: no cameras
            told.append(obs["task_description"])
        own = [bench._env.unwrapped.episode_spec(s).instruction for s in eval_seeds(SUITE, 3)]
        assert told == shuffled_instruction(own)
        hold = bench.layout.wire_actions(bench._env.unwrapped.agent.rest_action().numpy().reshape(-1))
        for _ in range(3):
            anyio.run(bench.apply_action, {"actions": hold})
        assert anyio.run(bench.is_done)
        record = anyio.run(bench.get_result)
    finally:
        bench.cleanup()
    assert (record["suite_id"], record["seed"], record["steps"], record["instruction"]) == (
        SUITE, EVAL_SEED_BASE + 2, 3, told[2])
    assert record["original_instruction"] == own[2] and record["gsr"] is False and record["tsr"] is False
    assert record["episode"]["question_id"] == record["question_id"]


def _rsb_records(n: int) -> list[dict]:
    """Records as RSBBenchmark's metrics hold them: one success, grasps without success, no grasps."""
    out = []
    for i in range(n):
        success, grasped = i == 0, i < n // 2 + 1
        out.append({"suite_id": SUITE, "seed": EVAL_SEED_BASE + i, "question_id": i, "instruction": f"q{i}",
                    "instruction_mode": "normal", "target_block": 0, "correct_letter": "A",
                    "first_grasped": 0 if grasped else -1, "grasped_any": grasped, "grasped_correct": success,
                    "placed_correct": success, "placed_wrong": False, "success": success, "steps": 10,
                    "policy": "pi05-rsb", "gsr": grasped, "tsr": success})
    return out


def test_report_reads_vla_eval_results_with_intervals(tmp_path, capsys):
    collector = ResultCollector("RSBBenchmark", metric_keys=RSBBenchmark(SUITE).get_metric_keys())
    for i, metrics in enumerate(_rsb_records(6)):
        collector.record(SUITE, {"episode_id": i, "metrics": metrics, "steps": 10})
    collector.record(SUITE, {"episode_id": 6, "metrics": {"success": False}, "failure_reason": "timeout",
                             "suite": SUITE, "episode_idx": 6})
    result = collector.get_benchmark_result(config={"params": {"policy_name": "pi05-rsb"}})
    # vla-eval's means: success over all 7 episodes, gsr over the 6 that hold one; no nSG, no intervals
    assert result["mean_success"] == pytest.approx(1 / 7, abs=1e-4)
    assert result["mean_gsr"] == pytest.approx(4 / 6, abs=1e-4)
    assert "nsg" not in json.dumps(result) and "low" not in json.dumps(result)
    (tmp_path / "RSBBenchmark_aggregate.json").write_text(json.dumps(result))
    with pytest.warns(UserWarning, match="1 episode"):
        assert main(["report", str(tmp_path)]) == 0
    shown = capsys.readouterr().out
    assert "| RSB-Math-4 | 7 | 57.1 [25.0, 84.2] | 14.3 [2.6, 51.3] | 0.0 [-27.3, 59.9] | 25.0 |" in shown
    summary = json.loads((tmp_path / "summary.json").read_text())["rows"]["pi05-rsb"]["suites"][SUITE]
    assert (summary["n_episodes"], summary["n_grasped"], summary["n_success"]) == (7, 4, 1)
    assert (tmp_path / "report.html").is_file()
    bad = {"tasks": [{"task": "libero_10", "episodes": [{"episode_id": 0, "metrics": {"success": True}}]}]}
    with pytest.raises(NotRSBResults, match="not a vla-eval run of rsb_maniskill.integrations.vla_eval"):
        records_from_results(bad)


# ---------------------------------------------------------------- both paths on the real task
@pytest.fixture
def env_capture(monkeypatch, eval_workers_here):
    """The envs `rsb eval` and RSBBenchmark build (jobs.make_env), for the oracle server to plan on: built in
    this process (eval_workers_here), where the oracle server reads them."""
    from rsb_maniskill.evaluation import jobs

    made, make = [], jobs.make_env
    monkeypatch.setattr(jobs, "make_env", lambda job: made.append(make(job)) or made[-1])
    return made


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_rsb_eval_remote_with_vla_eval_servers(tmp_path, env_capture):
    """Oracle chunks (RoboTwin keys, gripper 1 = closed, delta joints on the wire) reach TSR 100 %;
    random chunks on 64 x 48 cameras, rendered once per chunk of 5, GSR 0."""
    layout = make_layout("robotwin", gripper="closed", joints="delta")
    oracle = OracleServer(lambda: env_capture[-1], layout)
    with serve_background(oracle) as handle:
        assert main(["eval", "remote", "-a", "protocol=vla-eval", "-a", f"host={handle.url}", "-a", "port=null",
                     "-a", "preset=robotwin", "-a", "gripper=closed", "-a", "joints=delta", "-o", "state_dict",
                     "--name", "oracle-vla-eval", "--suites", SUITE, "-n", "2", "--out", str(tmp_path), "-q"]) == 0
    random = RandomServer(horizon=5)
    with serve_background(random) as handle:
        assert main(["eval", "remote", "-a", "protocol=vla-eval", "-a", f"host={handle.url}", "-a", "port=null",
                     "-a", "chunk_size=5", "-e", "camera_size=[64,48]", "--max-steps", "40", "--name", "random",
                     "--suites", SUITE, "-n", "2", "--out", str(tmp_path), "-q"]) == 0
    records = read_records(tmp_path / "episodes.jsonl")
    oracle_rows = [r for r in records if r["policy"] == "oracle-vla-eval"]
    assert [r["seed"] for r in oracle_rows] == eval_seeds(SUITE, 2) and all(r["success"] for r in oracle_rows)
    assert all("joint_state" in o and "images" not in o for o in oracle.seen)
    random_rows = [r for r in records if r["policy"] == "random"]
    assert len(random_rows) == 2 and not any(r["grasped_any"] or r["success"] for r in random_rows)
    # one predict() per chunk of 5, each on a rendered observation
    assert len(random.seen) == sum(-(-r["steps"] // 5) for r in random_rows)
    assert all(o["images"]["cam_high"].shape == (48, 64, 3) and o["images"]["cam_high"].std() > 5
               for o in random.seen)
    assert (tmp_path / "report.html").is_file()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_rsb_benchmark_in_vla_eval(tmp_path, env_capture):
    """The example configs in vla-eval: `vla_eval.evaluate` (in-process) with the oracle, TSR 100 %;
    `vla-eval run --no-docker` (its CLI, in another process) with random chunks on small cameras rendered
    every 5 steps, RoboTwin keys, GSR 0; `rsb report` reads both results files."""
    import vla_eval

    oracle = OracleServer(lambda: env_capture[-1], PRESETS["lerobot"], chunk_size=10_000)
    results = vla_eval.evaluate(oracle, EXAMPLES / "rsb_paper.yaml", output_dir=tmp_path / "oracle", docker=False,
                                benchmark_overrides={"episodes_per_task": 2, "params": {
                                    "suites": [SUITE], "episodes": 2, "obs_mode": "state_dict", "render_every": 1,
                                    "policy_name": "oracle"}})
    assert results[0]["mean_tsr"] == 1.0 and results[0]["mean_success"] == 1.0
    episodes = results[0]["tasks"][0]["episodes"]
    assert [e["metrics"]["seed"] for e in episodes] == eval_seeds(SUITE, 2)
    assert all(e["metrics"]["runner"] == "vla-eval" and e["metrics"]["steps"] == e["steps"] for e in episodes)

    random = RandomServer(horizon=5)
    with serve_background(random) as handle:
        cli = Path(sys.executable).parent / "vla-eval"
        res = subprocess.run([str(cli), "run", "--no-docker", "-c", str(EXAMPLES / "rsb_paper_robotwin.yaml"),
                              "--server-url", handle.url, "--output-dir", str(tmp_path / "random"),
                              "--benchmark-field", "episodes_per_task=2", "--benchmark-field", "max_steps=30",
                              "--param", f"suites=[{SUITE}]", "--param", "camera_size=[64,48]",
                              "--param", "render_every=5", "--param", "policy_name=random"],
                             capture_output=True, text=True, timeout=240, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert res.returncode == 0, res.stderr[-3000:]
    steps = [e["steps"] for e in json.loads((tmp_path / "random" / "RSB_aggregate.json").read_text())[
        "tasks"][0]["episodes"]]
    assert len(random.seen) == sum(-(-n // 5) for n in steps)  # the server predicted on rendered observations only
    assert all(o["images"]["head_camera"].shape == (48, 64, 3) and "joint_state" in o for o in random.seen)
    for out, policy, tsr in ((tmp_path / "oracle", "oracle", 100.0), (tmp_path / "random", "random", 0.0)):
        assert main(["report", str(out)]) == 0
        row = json.loads((out / "summary.json").read_text())["rows"][policy]["suites"][SUITE]
        assert row["n_episodes"] == 2 and 100 * row["tsr"]["value"] == tsr and row["tsr"]["low"] is not None
        if policy == "random":
            assert row["gsr"]["value"] == 0.0
