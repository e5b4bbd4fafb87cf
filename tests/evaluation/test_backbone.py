"""`rsb backbone`: the built-in backbones, user and remote ones, the instruction ablations, resume and
errors, and the semantic gap joined with an eval run's records (no physics; --images renders)."""
from __future__ import annotations

import json
import sys
import textwrap

import numpy as np
import pytest

from rsb_maniskill.audit.readers import SimilarityBackbone
from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.backbone import ArithmeticBackbone, ask_episodes, load_backbone
from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS, eval_seeds, shuffled_instruction
from rsb_maniskill.evaluation.store import BACKBONE_FILE, read_backbone_records
from rsb_maniskill.reporting.sections.gap import gap_markdown, gap_table
from rsb_maniskill.semantic import EpisodeSampler


def rsb_backbone(*args: str) -> int:
    return main(["backbone", *args, "-q"])


def specs(suite: str, n: int):
    sampler = EpisodeSampler(suite, **EVAL_ENV_KWARGS)
    return [sampler.episode(s) for s in eval_seeds(suite, n)]


def test_arithmetic_solves_math_exactly_and_abstains_elsewhere(tmp_path, question_data):
    out = tmp_path / "res"
    assert rsb_backbone("arithmetic", "--suites", "RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "-n", "500",
                        "--out", str(out)) == 0
    records = read_backbone_records(out / BACKBONE_FILE)
    by_suite = {s: [r for r in records if r["suite_id"] == s] for s in ("RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4")}
    assert all(len(v) == 500 for v in by_suite.values())
    assert all(r["correct"] and r["stated_letter"] == r["correct_letter"] for s in ("RSB-Math-4", "RSB-Math-10")
               for r in by_suite[s])
    assert all(r["text"] == "" and r["stated_letter"] is None and not r["correct"] for r in by_suite["RSB-HardMath-4"])
    # the question asked is the one the policy gets: the eval split's unseen-template instruction
    spec = specs("RSB-Math-10", 1)[0]
    first = by_suite["RSB-Math-10"][0]
    assert first["instruction"] == spec.instruction and first["question_id"] == spec.question_id
    assert json.loads((out / "run.json").read_text())["backbones"]["arithmetic"]["images"] is False


def test_instruction_ablations_are_those_of_rsb_eval(tmp_path):
    path = tmp_path / BACKBONE_FILE
    seeds = eval_seeds("RSB-Math-4", 12)
    own = [s.instruction for s in specs("RSB-Math-4", 12)]
    blank = ask_episodes(ArithmeticBackbone(), "RSB-Math-4", seeds, path, label="a", instruction_mode="blank",
                         progress=False)
    assert all(r["instruction"] == "" and r["stated_letter"] is None for r in blank)
    assert [r["original_instruction"] for r in blank] == own
    shuffled = ask_episodes(ArithmeticBackbone(), "RSB-Math-4", seeds, path, label="a", instruction_mode="shuffled",
                            progress=False)
    assert [r["instruction"] for r in shuffled] == shuffled_instruction(own)  # the protocol's donors
    # it answers the donor's question: right only where the donor's value is also this episode's answer
    assert sum(r["correct"] for r in shuffled) <= 3


def test_resume_and_settings_check(tmp_path, capsys):
    out = tmp_path / "res"
    assert rsb_backbone("arithmetic", "--suites", "RSB-Math-4", "-n", "5", "--out", str(out)) == 0
    first = read_backbone_records(out / BACKBONE_FILE)
    assert rsb_backbone("arithmetic", "--suites", "RSB-Math-4", "-n", "9", "--out", str(out)) == 0
    both = read_backbone_records(out / BACKBONE_FILE)
    assert len(both) == 9 and both[:5] == first
    assert len((out / BACKBONE_FILE).read_text().splitlines()) == 9  # the first five were not asked again
    capsys.readouterr()
    assert rsb_backbone("arithmetic", "--suites", "RSB-Math-4", "-n", "5", "--images", "--out", str(out)) == 2
    assert "other settings (images: False before, True now)" in capsys.readouterr().err
    assert rsb_backbone("nonesuch", "--suites", "RSB-Math-4", "--out", str(out)) == 2
    assert "neither a built-in" in capsys.readouterr().err
    assert rsb_backbone("no_such_module_xyz:make", "--suites", "RSB-Math-4", "--out", str(out)) == 2
    assert "cannot import module" in capsys.readouterr().err
    assert len(read_backbone_records(out / BACKBONE_FILE)) == 9  # nothing lost


def test_user_backbone_module_factory(tmp_path, monkeypatch):
    (tmp_path / "my_backbones.py").write_text(textwrap.dedent("""
        class Letter:
            def __init__(self, letter="B"):
                self.letter = letter
            def answer(self, instruction, images):
                return f"The answer is ({self.letter})." if instruction else ""
        def broken():
            return object()
        class Mute:
            def answer(self, instruction, images):
                return None
        class Number:
            def answer(self, instruction, images):
                return 10
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "res"
    assert rsb_backbone("my_backbones:Letter", "-a", "letter=C", "--suites", "RSB-Math-4", "-n", "8", "--name",
                        "say-C", "--out", str(out)) == 0
    records = read_backbone_records(out / BACKBONE_FILE)
    assert {r["backbone"] for r in records} == {"say-C"} and {r["stated_letter"] for r in records} == {"C"}
    assert [r["correct"] for r in records] == [s.correct_letter == "C" for s in specs("RSB-Math-4", 8)]
    with pytest.raises(TypeError, match="lacks answer"):
        load_backbone("my_backbones:broken")
    mute = ask_episodes(load_backbone("my_backbones:Mute"), "RSB-Math-4", eval_seeds("RSB-Math-4", 2),
                        tmp_path / "m.jsonl", label="mute", progress=False)
    assert [(r["text"], r["stated_letter"], r["correct"]) for r in mute] == [("", None, False)] * 2
    with pytest.raises(TypeError, match="must return a str, got int"):
        ask_episodes(load_backbone("my_backbones:Number"), "RSB-Math-4", eval_seeds("RSB-Math-4", 2),
                     tmp_path / "n.jsonl", label="n", progress=False)
    sys.modules.pop("my_backbones", None)


def test_similarity_is_the_audits_reader_on_the_instruction(question_data):
    from rsb_maniskill.audit.readers import SimilarityReader

    backbone, reader = SimilarityBackbone(), SimilarityReader()
    for spec in specs("RSB-General-10", 12):
        said = backbone.answer(spec.instruction, {})
        best = spec.letters[int(np.argmax(reader.score(spec.question, spec.options)))]
        assert said == f"option {best}"
    assert backbone.answer("", {}) == ""  # a blank instruction: nothing to read


@pytest.mark.timeout(60)
def test_remote_backbone_answers_as_the_local_one(tmp_path):
    from rsb_maniskill.policies.remote.server import PolicyServer

    seeds = eval_seeds("RSB-Math-4", 6)
    local = ask_episodes(ArithmeticBackbone(), "RSB-Math-4", seeds, tmp_path / "a.jsonl", label="x", progress=False)
    with PolicyServer(ArithmeticBackbone(), host="127.0.0.1", port=0) as server:
        remote = load_backbone("remote", port=server.port, connect_timeout=10, request_timeout=10)
        try:
            got = ask_episodes(remote, "RSB-Math-4", seeds, tmp_path / "b.jsonl", label="x", progress=False)
        finally:
            remote.close()
    strip = lambda rs: [{k: v for k, v in r.items() if k != "wall_s"} for r in rs]  # noqa: E731
    assert strip(got) == strip(local) and all(r["correct"] for r in got)


def _episode_records(policy: str, suite: str, n: int, picks) -> list[dict]:
    """Eval records of the protocol's episodes: ``picks(spec)`` -> the block grasped (None: no grasp)."""
    out = []
    for spec in specs(suite, n):
        block = picks(spec)
        right = block == spec.target_block
        out.append({"policy": policy, "suite_id": suite, "seed": spec.seed, "question_id": spec.question_id,
                    "instruction": spec.instruction, "instruction_mode": "normal", "target_block": spec.target_block,
                    "correct_letter": spec.correct_letter, "first_grasped": -1 if block is None else block,
                    "grasped_any": block is not None, "grasped_correct": right, "placed_correct": right,
                    "placed_wrong": block is not None and not right, "success": right, "steps": 10})
    return out


def test_the_gap_joins_only_the_same_episodes(tmp_path):
    suite = "RSB-Math-4"
    answers = ask_episodes(ArithmeticBackbone(), suite, eval_seeds(suite, 40), tmp_path / "b.jsonl", label="arithmetic",
                           progress=False)
    # a policy grasping block seed % 4 (right a quarter of the time), and one grasping nothing on odd seeds
    episodes = _episode_records("cyclic", suite, 40, lambda s: s.seed % 4)
    episodes += _episode_records("half", suite, 40, lambda s: s.target_block if s.seed % 2 else None)
    gaps, skipped = gap_table(episodes, answers)
    by = {g.policy: g for g in gaps}
    cyc = by["cyclic"]
    right = sum(r["success"] for r in episodes[:40])
    assert cyc.accuracy.value == 1.0 and cyc.n_grasped == 40 and cyc.tsr_gsr.value == right / 40
    assert cyc.crossing == {"right/right": right, "right/wrong": 40 - right, "wrong/right": 0, "wrong/wrong": 0}
    assert cyc.gap.value == (40 - right) / 40 and cyc.gap.low < cyc.gap.value < cyc.gap.high
    half = by["half"]
    assert half.n_grasped == 20 and half.gap.value == 0.0 and half.tsr.value == 0.5 and half.nsg.value == 1.0
    assert not skipped
    # other seeds, or other episodes behind the same seeds, are not joined
    fewer = [r for r in episodes[:40] if r["seed"] < eval_seeds(suite, 30)[-1]]
    other = [dict(r, policy="other-data", instruction=r["instruction"] + " ") for r in episodes[:40]]
    gaps, skipped = gap_table(fewer + other, answers)
    assert not gaps and {s.policy for s in skipped} == {"cyclic", "other-data"}
    assert "seeds differ" in gap_markdown((gaps, skipped)) and "episodes differ" in gap_markdown((gaps, skipped))
    # another instruction mode is another row: never paired
    blank = [dict(r, instruction_mode="blank", instruction="") for r in episodes[:40]]
    assert gap_table(blank, answers) == ([], [])


@pytest.mark.slow
def test_images_are_the_first_head_frame(tmp_path, monkeypatch):
    """--images renders the eval env: the frame sent is the first observation's head camera."""
    import gymnasium as gym

    class Shapes:
        def __init__(self):
            self.seen = []

        def answer(self, instruction, images):
            self.seen.append({k: v.copy() for k, v in images.items()})
            return "option A"

    backbone = Shapes()
    seeds = eval_seeds("RSB-Math-4", 2)
    records = ask_episodes(backbone, "RSB-Math-4", seeds, tmp_path / "b.jsonl", label="s", images=True,
                           progress=False)
    assert [r["images"] for r in records] == [True, True]
    env = gym.make("RSB-Math-4", obs_mode="rgb", **EVAL_ENV_KWARGS)
    try:
        obs, _ = env.reset(seed=seeds[1])
        expected = obs["sensor_data"]["head_camera"]["rgb"][0].cpu().numpy()
    finally:
        env.close()
    assert list(backbone.seen[1]) == ["head"] and backbone.seen[1]["head"].dtype == np.uint8
    assert np.array_equal(backbone.seen[1]["head"], expected)
