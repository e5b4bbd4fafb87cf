"""Robustness axes (issue 26): names and levels, language axes, visual axes in the scene, the eval sweep."""
from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch

import rsb_maniskill  # noqa: F401
from rsb_maniskill import perturb as P
from rsb_maniskill.audit.run import audit_suite
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.objects import layout
from rsb_maniskill.semantic import EpisodeSampler, wording
from rsb_maniskill.semantic.records import normalize_text
from rsb_maniskill.semantic.stable import axis_rng
from rsb_maniskill.semantic.templates import get_template
from rsb_maniskill.tasks.perturb_scene import CLUTTER_ITEMS, clutter_layout

from task_envs import HELPERS, SEED, _digest, _head, _visual_digests

LANG_SUITES = [("RSB-Math-4", "blocks"), ("RSB-Math-10", "blocks"), ("RSB-Math-4", "objects"),
               ("RSB-Direct-10", "blocks")]


# ---------------------------------------------------------------- names and levels
def test_parse_perturb_forms_and_level_zero():
    assert P.parse_perturb(None) == {}
    assert P.parse_perturb({"camera": 2, "noise": 0}) == {"camera": 2}
    assert P.parse_perturb("camera=2, lang_layout=1") == {"camera": 2, "lang_layout": 1}
    assert P.label({"noise": 1, "camera": 2}) == "camera=2,noise=1" and P.label({}) == "none"
    assert set(P.AXES) == set(P.VISUAL_AXES) | set(P.LANGUAGE_AXES)


@pytest.mark.parametrize("bad, words", [({"camra": 1}, ["unknown perturbation axis 'camra'", "camera"]),
                                        ({"camera": 4}, ["'camera'", "0, 1, 2, 3", "got 4"]),
                                        ({"camera": True}, ["got True"]), ("camera", ["AXIS=LEVEL"])])
def test_bad_perturbations_fail_in_one_line_naming_the_fix(bad, words):
    with pytest.raises(P.PerturbError) as err:
        P.parse_perturb(bad)
    msg = str(err.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


def test_env_rejects_a_bad_perturbation_before_building():
    with pytest.raises(P.PerturbError, match="valid: camera"):
        gym.make("RSB-Math-4", obs_mode="state", render_backend="none", perturb={"fog": 1})


def test_axis_draws_depend_on_seed_axis_and_level_only():
    a = axis_rng("RSB-Math-4", "test", 5, "camera", 2).random(4)
    assert np.array_equal(a, axis_rng("RSB-Math-4", "test", 5, "camera", 2).random(4))
    for other in (("RSB-Math-4", "test", 6, "camera", 2), ("RSB-Math-4", "test", 5, "camera", 3),
                  ("RSB-Math-4", "test", 5, "lighting", 2), ("RSB-Math-4", "train", 5, "camera", 2)):
        assert not np.array_equal(a, axis_rng(*other).random(4)), other


# ---------------------------------------------------------------- language axes
@pytest.mark.parametrize("suite_id, targets", LANG_SUITES)
@pytest.mark.parametrize("axis", list(P.LANGUAGE_AXES))
def test_language_axes_reword_only(suite_id, targets, axis, question_data):
    """Same question, options, binding and answer at every level; one correct option, every option
    still in the instruction; the wording changes with the level (Direct: its axes only)."""
    base = EpisodeSampler(suite_id, "test", targets=targets)
    direct = suite_id.startswith("RSB-Direct")
    reworded = {1: 0, 2: 0, 3: 0}
    seeds = range(SEED, SEED + 16)
    for seed in seeds:
        ref = base.episode(seed)
        texts = {ref.instruction}
        for level in (1, 2, 3):
            sp = EpisodeSampler(suite_id, "test", targets=targets, perturb={axis: level}).episode(seed)
            assert (sp.question, sp.options, sp.answer_slot, sp.block_of_option, sp.candidates) == \
                (ref.question, ref.options, ref.answer_slot, ref.block_of_option, ref.candidates)
            assert sp.correct_option == ref.correct_option and sp.target_block == ref.target_block
            if not direct:
                for opt in sp.options:
                    assert normalize_text(opt) in sp.instruction, (opt, sp.instruction)
                assert normalize_text(sp.question) in sp.instruction
            texts.add(sp.instruction)
            reworded[level] += sp.instruction != ref.instruction
    # A template without a candidate's name or noun has nothing for lang_reference to rename, and
    # one whose own entries read like a layout level keeps that level's text: most episodes change.
    changes = not direct or axis in ("lang_reference", "lang_distractor")
    for level, n in reworded.items():
        assert (n >= 0.6 * len(seeds)) if changes else n == 0, (level, n)


def test_language_rendering_takes_no_answer():
    """The instruction is a function of question, options, names and binding: rebuilt from them
    without the answer it is the recorded one."""
    for fn in (wording.render, wording.render_direct_perturbed, wording.add_distractors):
        assert not {"answer", "answer_slot", "correct", "target"} & set(inspect.signature(fn).parameters)
    perturb = {"lang_reference": 3, "lang_layout": 2, "lang_distractor": 3, "lang_order": 1}
    s = EpisodeSampler("RSB-Math-4", "test", targets="objects", perturb=perturb)
    for seed in range(SEED, SEED + 8):
        sp = s.episode(seed)
        rngs = {a: axis_rng(sp.suite_id, "test", seed, a, lv) for a, lv in perturb.items()}
        again = wording.render(get_template(4, sp.template_id, lettered=False), sp.question, sp.options, sp.letters,
                               sp.block_names, sp.candidates, sp.block_of_option, "object", perturb, rngs)
        assert again == sp.instruction


def test_reference_names_stay_distinct_and_never_name_another_category():
    from rsb_maniskill.objects.catalog import CATEGORY_KEYS, category_name

    names = [category_name(k) for k in CATEGORY_KEYS]
    assert set(wording.OBJECT_NAMES) == set(names)
    for level in (1, 2, 3):
        words = [wording.OBJECT_NAMES[n][level - 1] for n in names]
        assert len(set(words)) == len(words), level
        for n, w in zip(names, words):
            assert not any(other != n and other in w for other in names), (n, w)
    colours = wording.reference_names(["red block"] * 4, [f"block:{c}" for c in wording.COLOUR_WORDS], 2)
    assert colours == ("crimson block", "emerald block", "sapphire block", "golden block")


def test_distractors_name_no_option_letter_number_or_candidate():
    from rsb_maniskill.objects.catalog import CATEGORY_KEYS, category_name

    for s in wording.DISTRACTORS:
        assert not any(ch.isdigit() for ch in s)
        assert not any(f" {c} " in f" {s[:-1]} " for c in "ABCDEFGHIK")
        assert not any(category_name(k) in s.lower() for k in CATEGORY_KEYS)
        assert not any(c in s.lower() for c in ("red", "green", "blue", "yellow", "block"))


def test_language_axes_are_deterministic_across_processes(question_data):
    code = ("from rsb_maniskill.semantic import EpisodeSampler\n"
            "import json\n"
            "print(json.dumps([EpisodeSampler('RSB-Math-10', 'test', perturb={'lang_distractor': 3, "
            f"'lang_reference': 2}}).episode(s).instruction for s in range({SEED}, {SEED} + 5)]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    s = EpisodeSampler("RSB-Math-10", "test", perturb={"lang_distractor": 3, "lang_reference": 2})
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [s.episode(x).instruction for x in range(SEED, SEED + 5)]


# The 10-choice audits cost ~15-55 s each on the 2-core machine: slow set (`-m slow`).
@pytest.mark.parametrize("suite_id", ["RSB-Math-4", pytest.param("RSB-Math-10", marks=pytest.mark.slow),
                                      "RSB-Direct-4"])
@pytest.mark.parametrize("axis", list(P.LANGUAGE_AXES))
def test_language_axes_pass_the_audit(axis, suite_id):
    """Every language axis at its strongest level, on a 4- and a 10-choice suite: no answer-blind
    guesser (the four wording guessers included) and no probe beats chance + 3 points (400 episodes:
    a wording that put the answer somewhere special scores far above that). A Direct instruction
    names its target by design: the wording guessers abstain there instead of reading it."""
    a = audit_suite(suite_id, "test", 400, n_train=200, perturb={axis: 3})
    assert a.passed, [(g.name, g.accuracy) for g in a.flagged]
    wording = {g.name: g for g in a.guessers if g.name in ("mentioned first", "mentioned last", "mentioned most",
                                                           "next to an added sentence")}
    assert len(wording) == 4
    if suite_id.startswith("RSB-Direct"):
        assert all(g.applies == 0 for g in wording.values()), {n: g.applies for n, g in wording.items()}


# ---------------------------------------------------------------- clutter placement (no physics)
@pytest.mark.parametrize("targets", ["blocks", "objects"])
def test_clutter_in_free_cells_inside_them_and_out_of_the_zone(targets):
    from rsb_maniskill.objects.family import get_family
    from rsb_maniskill.tasks.answer_selection import ZONE_HALF, ZONE_XY

    lay = get_family(targets).layout
    cells = layout.grid(lay)
    rng = np.random.default_rng(0)
    for seed in range(300):
        used = rng.choice(len(cells), size=4, replace=False)
        placed = clutter_layout(axis_rng("RSB-Math-4", "test", seed, "clutter", 3), 3, cells, lay.pitch, used)
        assert len(placed) == P.CLUTTER_COUNT[3] and len({k for k, _ in placed}) == len(placed)
        for k, xy in placed:
            hx, hy = CLUTTER_ITEMS[k].half_extents
            d = np.abs(cells - xy)
            cell = int(np.argmin(d.sum(1)))
            assert cell not in used, "clutter never shares a candidate's cell"
            assert d[cell, 0] + hx <= lay.pitch[0] / 2 and d[cell, 1] + hy <= lay.pitch[1] / 2, "inside its cell"
            gap = np.abs(xy - np.asarray(ZONE_XY)) - np.array([hx, hy]) - ZONE_HALF
            assert gap.max() > 0, "never over the answer zone"


# ---------------------------------------------------------------- visual axes in the scene
def test_level_zero_is_byte_identical_to_no_perturbation():
    plain = _head(None, steps=3)
    zero = _head({a: 0 for a in P.AXES}, steps=3)
    assert plain["instruction"] == zero["instruction"]
    for key in ("rgb", "depth"):
        assert plain[key].tobytes() == zero[key].tobytes(), key
    assert torch.equal(plain["state"]["actors"]["candidate_block_A"], zero["state"]["actors"]["candidate_block_A"])


VISUAL_DIGEST_SCRIPT = """
import json, sys
sys.path.insert(0, {tests!r})
from task_envs import _visual_digests
print(json.dumps(_visual_digests()))
"""


@pytest.mark.slow
def test_every_visual_axis_shows_and_is_deterministic_across_processes():
    here = _visual_digests()
    base = _digest(_head(None, obs_mode="rgb")["rgb"])
    assert all(d != base for d in here.values()), [a for a, d in here.items() if d == base]
    code = VISUAL_DIGEST_SCRIPT.format(tests=HELPERS)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=600)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == here


def test_noise_has_the_level_spread_and_changes_per_step():
    clean = _head(None)
    noisy = _head({"noise": 3})
    diff = noisy["rgb"].astype(float) - clean["rgb"].astype(float)
    assert 0.8 * P.NOISE_RGB[3] < diff.std() < 1.2 * P.NOISE_RGB[3]
    assert noisy["depth"].astype(float).std() > 0 and (noisy["depth"] != clean["depth"]).mean() > 0.5
    diff2 = _head({"noise": 3}, steps=2)["rgb"].astype(float) - _head(None, steps=2)["rgb"].astype(float)
    assert not np.array_equal(diff, diff2), "new noise each step"


@pytest.mark.parametrize("axis", ["camera", "lighting", "table", "noise", "candidate"])
def test_image_only_axes_leave_the_physics_alone(axis):
    a, b = _head(None, obs_mode="state", steps=5), _head({axis: 3}, obs_mode="state", steps=5)
    for group in ("actors", "articulations"):
        for name, value in a["state"][group].items():
            assert torch.equal(value, b["state"][group][name]), (axis, name)


def test_robot_init_offsets_the_arm_joints_within_the_level():
    env = gym.make("RSB-Math-4", obs_mode="state", split="test", render_backend="none", perturb={"robot_init": 3})
    env.reset(seed=SEED)
    u = env.unwrapped
    rest = torch.as_tensor(u.agent.keyframes["rest"].qpos, dtype=torch.float32)
    d = u.agent.robot.get_qpos()[0] - rest
    arm = [c for a in u.agent.arms for c in u.agent.arm_qpos_index[a]]
    assert 0.01 < d[arm].abs().max() <= P.ROBOT_JOINT_JITTER[3] + 1e-5
    others = [i for i in range(len(d)) if i not in arm]
    assert d[others].abs().max() < 1e-6, "grippers start as they do unperturbed"
    env.close()


@pytest.mark.parametrize("suite_id, count", [("RSB-Math-4", 4), ("RSB-Math-10-Objects", 2)])
def test_clutter_rests_on_the_table_clear_of_the_candidates(suite_id, count):
    env = gym.make(suite_id, obs_mode="state", split="test", render_backend="none", perturb={"clutter": 3})
    u = env.unwrapped
    for seed in (SEED, SEED + 1):
        env.reset(seed=seed)
        before = u.pool.raw_poses()[0, :, :3].clone()
        for _ in range(15):
            env.step(u.agent.rest_action()[None])
        on_table = [(item, a.pose.p[0]) for item, a in zip(CLUTTER_ITEMS, u.axes.clutter) if a.pose.p[0, 2] > 0]
        free = len(layout.grid(u.family.layout)) - u.n_choices  # objects: 12 cells, 10 candidates, 2 free
        assert len(on_table) == min(P.CLUTTER_COUNT[3], free) == count
        for item, p in on_table:
            assert abs(float(p[2]) - item.half_height) < 2e-3, f"{item.name} rests on the table"
        assert torch.allclose(u.pool.raw_poses()[0, :, :3], before, atol=2e-3), "no candidate was pushed"
        assert not u.evaluate()["placed_wrong"].any()
    env.close()


@pytest.mark.slow
def test_perturbed_expert_demo_replays_with_maniskills_tool(tmp_path):
    """Clutter and start pose come back under ManiSkill's replay tool (fresh process): the replayed
    actions succeed again."""
    from rsb_maniskill.motionplan.config import GenerateConfig
    from rsb_maniskill.motionplan.generate import generate

    summary = generate(GenerateConfig(env_id="RSB-Math-4", out=str(tmp_path / "demos"), progress=False, num=1,
                                      env_kwargs={"perturb": {"clutter": 3, "robot_init": 3}}))
    assert summary.completed == 1, summary
    data = json.loads(summary.path.with_suffix(".json").read_text())
    assert data["env_info"]["env_kwargs"]["perturb"] == {"clutter": 3, "robot_init": 3}
    src = tmp_path / "copy.h5"  # the replay writes <stem>.state.pd_joint_pos.physx_cpu.h5 next to it
    src.write_bytes(summary.path.read_bytes())
    src.with_suffix(".json").write_bytes(summary.path.with_suffix(".json").read_bytes())
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    res = subprocess.run([sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
                          str(src), "-o", "state", "--save-traj"],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "1/1=100.00% demos saved" in res.stdout
    import h5py

    with h5py.File(src, "r") as a, h5py.File(tmp_path / "copy.state.pd_joint_pos.physx_cpu.h5", "r") as b:
        sa, sb = a["traj_0/env_states"], b["traj_0/env_states"]
        clutter = [k for k in sa["actors"] if k.startswith("clutter_")]
        assert sum(float(sa["actors"][k][0, 2]) > 0 for k in clutter) == P.CLUTTER_COUNT[3]
        for k in clutter:  # the replayed episode starts with the same clutter ...
            np.testing.assert_allclose(sa["actors"][k][0], sb["actors"][k][0], atol=1e-6)
        robot = next(iter(sa["articulations"]))  # ... and the same perturbed start pose
        np.testing.assert_allclose(sa["articulations"][robot][0], sb["articulations"][robot][0], atol=1e-6)


@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")
def test_gpu_per_env_perturbations_match_cpu():
    perturb = {"robot_init": 2, "clutter": 2, "table": 2, "candidate": 2}
    env = gym.make("RSB-Math-10", num_envs=4, obs_mode="state", sim_backend="physx_cuda", perturb=perturb)
    env.reset(seed=[SEED + i for i in range(4)])
    u = env.unwrapped
    cpu = gym.make("RSB-Math-10", obs_mode="state", perturb=perturb)
    qpos = u.agent.robot.get_qpos().cpu()
    assert len({tuple(q.tolist()) for q in qpos}) == 4, "each env its own start pose"
    for i in (0, 3):
        cpu.reset(seed=SEED + i)
        c = cpu.unwrapped
        assert torch.allclose(c.agent.robot.get_qpos()[0], qpos[i], atol=1e-4)
        for a_gpu, a_cpu in zip(u.axes.clutter, c.axes.clutter):
            if a_cpu.pose.p[0, 2] > 0:
                assert torch.allclose(a_gpu.pose.p[i].cpu(), a_cpu.pose.p[0], atol=1e-4)
        assert np.allclose(u.axes._table_mats[i][0].base_color, c.axes._table_mats[0][0].base_color)
    env.close()
    cpu.close()


# ---------------------------------------------------------------- rsb eval --sweep
def _eval(*args, out) -> int:
    """`rsb eval oracle` in this process, one worker (what a sweep records needs no episode played to
    its end: 5 steps each)."""
    from rsb_maniskill.cli import main

    return main(["eval", "oracle", "--suites", "RSB-Math-4", "-q", "--out", str(out), "--num-procs", "1",
                 "--max-steps", "5", *args])


def test_eval_sweep_records_axis_and_level_resumes_and_reports(tmp_path, question_data, capsys):
    assert _eval("-n", "2", "--sweep", "lang_layout", out=tmp_path) == 0, capsys.readouterr().err[-2000:]
    recs = [json.loads(line) for line in (tmp_path / "episodes.jsonl").read_text().splitlines()]
    assert len(recs) == 2 * 4
    levels = sorted((r.get("perturb_axis", ""), r.get("perturb_level", 0)) for r in recs)
    assert levels == sorted([("", 0)] * 2 + [("lang_layout", lv) for lv in (1, 2, 3) for _ in range(2)])
    by = {(r.get("perturb", "none"), r["seed"]): r for r in recs}
    assert by[("lang_layout=2", EVAL_SEED_BASE)]["instruction"] != by[("none", EVAL_SEED_BASE)]["instruction"]
    assert by[("lang_layout=2", EVAL_SEED_BASE)]["correct_letter"] == by[("none", EVAL_SEED_BASE)]["correct_letter"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    rows = [(r["axis"], r["level"], r["n_episodes"]) for r in summary["robustness"]]
    assert rows == [("lang_layout", lv, 2) for lv in range(4)]
    assert "### Robustness: oracle on RSB-Math-4" in (tmp_path / "summary.md").read_text()
    assert 'id="robustness"' in (tmp_path / "report.html").read_text()
    assert _eval("-n", "2", "--sweep", "lang_layout", out=tmp_path) == 0
    assert len((tmp_path / "episodes.jsonl").read_text().splitlines()) == 8, "resumed"


@pytest.mark.parametrize("args, words", [(("--perturb", "camera=7"), ["camera", "0, 1, 2, 3", "--perturb"]),
                                         (("--sweep", "fog"), ["unknown perturbation axis 'fog'", "--sweep"]),
                                         (("--sweep", "camera", "--perturb", "noise=1"), ["not both"])])
def test_eval_bad_perturbation_is_one_clear_line(tmp_path, args, words, capsys):
    assert _eval(*args, out=tmp_path) == 2
    err = capsys.readouterr().err
    line = [x for x in err.splitlines() if x.startswith("rsb eval: error")]
    assert len(line) == 1 and all(w in line[0] for w in words), err[-1000:]
