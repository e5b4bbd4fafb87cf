"""Counterfactual scenes over records: follow / switch / stuck rates on synthetic records, record
identity and resume per variant, the report's section, and the harnesses that refuse the mode."""
from __future__ import annotations

import json
import random

import pytest

from rsb_maniskill.evaluation.jobs import drive
from rsb_maniskill.evaluation.protocol import (
    check_ablation_mode,
    episode_of,
    eval_seeds,
    mode_episodes,
    record_episode,
    scene_variants,
)
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, dedupe, validate_record
from rsb_maniskill.evaluation.runner import EpisodeSettings
from rsb_maniskill.evaluation.store import RecordWriter, read_records
from rsb_maniskill.policies.reference import blind_target
from rsb_maniskill.reporting.sections.counterfactual import POOLED, counterfactual_json, counterfactual_table

SUITE = "RSB-Math-4"


def record(seed: int, variant: int, target: int, grasped: int, suite: str = SUITE, policy: str = "p") -> dict:
    return {"suite_id": suite, "seed": seed, "question_id": 0, "instruction": f"i{seed}.{variant}",
            "instruction_mode": COUNTERFACTUAL, "target_block": target, "correct_letter": "A",
            "first_grasped": grasped, "grasped_any": grasped >= 0, "grasped_correct": grasped == target,
            "placed_correct": grasped == target, "placed_wrong": False, "success": grasped == target, "steps": 9,
            "policy": policy, "variant": variant, "variant_kind": "protocol" if variant == 0 else
            ("remap" if variant % 2 else "requestion")}


def scenes(policy, n_scenes: int = 50, n: int = 4, k: int = 4, suite: str = SUITE, seed: int = 0) -> list[dict]:
    """Records of a policy ``policy(rng, target, scene_pick) -> grasped`` on scenes of K distinct targets."""
    rng = random.Random(seed)
    out = []
    for s in range(n_scenes):
        targets = rng.sample(range(n), k)
        pick = rng.randrange(n)  # what a policy that ignores the instruction takes in this scene
        out += [record(10_000_000 + s, v, t, policy(rng, t, pick), suite) for v, t in enumerate(targets)]
    return out


def metrics(records, suite=SUITE):
    (row,) = counterfactual_table(records).values()
    return row[suite]


def test_a_policy_that_follows():
    m = metrics(scenes(lambda rng, t, pick: t))
    assert (m.follow.value, m.follow_all.value, m.switch.value, m.stuck.value) == (1.0, 1.0, 1.0, 0.0)
    assert m.counts.pairs == 50 * 6 and m.counts.full_scenes == 50 and m.variants_per_scene == 4
    assert m.follow_by_kind["remap"].value == m.follow_by_kind["requestion"].value == 1.0
    assert (m.chance_follow, m.chance_switch, m.chance_stuck) == (0.25, 0.75, 0.25 ** 3)


def test_a_stuck_policy_follows_once_a_scene():
    """Grasping one candidate whatever the instruction: with K = N variants it follows exactly one."""
    m = metrics(scenes(lambda rng, t, pick: pick))
    assert m.follow_grasped.value == 0.25 and m.switch.value == 0.0 and m.stuck.value == 1.0
    assert m.stuck.low > 0.9 and m.switch.high < 0.1
    # the headline over the changed variants (k > 0): the scenes whose pick is a changed variant's target
    changed = [r for r in scenes(lambda rng, t, pick: pick) if r["variant"] > 0]
    assert m.follow.value == sum(r["first_grasped"] == r["target_block"] for r in changed) / len(changed)
    assert m.switched_and_followed.value == 0.0  # never two targets at once
    assert m.spread["all"] == 0 and m.spread["some"] + m.spread["none"] == 50


def test_switched_and_followed_and_the_spread_tell_a_guesser_from_a_follower():
    """Issue 49: a uniform guesser switches at chance (75 %), but rarely switches *and* follows both
    (1/16 of pairs) and seldom follows in all of a scene's changed variants; a follower does both always."""
    m = metrics(scenes(lambda rng, t, pick: rng.randrange(4), n_scenes=400))
    assert m.switch.low < 0.75 < m.switch.high
    assert m.switched_and_followed.low < 1 / 16 < m.switched_and_followed.high
    assert m.spread["all"] < 0.1 * 400 < m.spread["some"]
    follower = metrics(scenes(lambda rng, t, pick: t, n_scenes=20))
    assert follower.switched_and_followed.value == 1.0 and follower.spread == {"all": 20, "some": 0, "none": 0}


def test_a_uniform_grasper_is_at_chance():
    m = metrics(scenes(lambda rng, t, pick: rng.randrange(4), n_scenes=400))
    assert m.follow.low < 0.25 < m.follow.high and m.switch.low < 0.75 < m.switch.high
    assert m.stuck.value < 0.05


def test_the_switch_interval_holds_its_coverage_for_a_uniform_grasper():
    """Counted over scenes (the design effect of a scene's pairs), the interval covers the switch rate
    of a uniform grasper at least as often as a 95 % interval should."""
    misses = 0
    runs = 200
    for seed in range(runs):
        m = metrics(scenes(lambda rng, t, pick: rng.randrange(4), n_scenes=20, seed=seed))
        misses += not m.switch.low <= 0.75 <= m.switch.high
    assert misses <= 0.05 * runs, misses


def test_denominators_without_a_grasp():
    recs = [record(1, 0, 0, 0), record(1, 1, 1, -1), record(1, 2, 2, 0), record(1, 3, 3, -1),
            record(2, 0, 3, 3), record(2, 1, 1, 1)]
    m = metrics(recs)
    assert (m.counts.variants, m.counts.grasped) == (6, 4)
    assert m.follow_grasped.value == 3 / 4 and m.follow_all.value == 3 / 6
    assert m.follow.value == 1 / 2  # changed variants grasped: scene 1 variant 2 (followed), scene 2 variant 1
    assert m.counts.pairs == 2 and m.switch.value == 0.5  # (0, 2) of scene 1 stuck on 0; scene 2 switched
    assert m.counts.full_scenes == 1 and m.stuck.value == 0.0  # only scene 2 was grasped in every variant
    assert m.variants_per_scene is None  # scenes of 4 and 2 variants
    assert m.chance_stuck == 0.25  # scene 2: K = 2


def test_pooled_over_suites_weights_chance_by_the_denominator():
    four = scenes(lambda rng, t, pick: t, n_scenes=10)
    ten = scenes(lambda rng, t, pick: pick, n_scenes=30, n=10, suite="RSB-Math-10")
    row = next(iter(counterfactual_table(four + ten).values()))
    assert list(row) == [SUITE, "RSB-Math-10", POOLED]
    p = row[POOLED]
    assert p.n_choices is None and p.counts.scenes == 40
    assert p.chance_follow == pytest.approx((30 * 0.25 + 90 * 0.1) / 120)  # over the changed variants
    followed = sum(r["first_grasped"] == r["target_block"] for r in ten)  # 1 in scenes whose 4 targets hold it
    assert 0 < followed < 30 and row["RSB-Math-10"].follow_grasped.value == pytest.approx(followed / 120)
    assert p.follow_grasped.value == pytest.approx((40 + followed) / 160)
    changed = sum(r["first_grasped"] == r["target_block"] for r in ten if r["variant"] > 0)
    assert p.follow.value == pytest.approx((30 + changed) / 120)
    js = counterfactual_json(counterfactual_table(four + ten))
    assert js["definitions"]["chance"]["stuck"] == "(1/N)^(K-1)"
    assert json.loads(json.dumps(js))["rows"]["p (counterfactual)"][POOLED]["scenes"] == 40


def test_variants_of_one_seed_are_distinct_records_and_old_records_keep_their_identity():
    recs = [record(1, v, v, v) for v in range(4)]
    assert len(dedupe(recs + recs)) == 4
    old = {k: v for k, v in record(1, 0, 0, 0).items() if k not in ("variant", "variant_kind")}
    old["instruction_mode"] = "normal"
    assert dedupe([old, {**old, "variant": 0}]) == [old]  # no variant field reads as variant 0
    validate_record(recs[1])
    with pytest.raises(ValueError, match="variant"):
        validate_record({k: v for k, v in recs[1].items() if k != "variant"})


def test_episodes_and_resume_go_variant_by_variant(tmp_path):
    seeds = eval_seeds(SUITE, 3)
    settings = EpisodeSettings(suite_id=SUITE, seeds=seeds, label="p", instruction_mode=COUNTERFACTUAL)
    assert settings.variants == 4 == scene_variants(SUITE)
    assert settings.episodes() == mode_episodes(seeds, COUNTERFACTUAL, 4) == [(s, k) for s in seeds for k in range(4)]
    assert [episode_of(e) for e in settings.episodes()[:2]] == [(seeds[0], 0), (seeds[0], 1)]
    assert episode_of(seeds[0]) == (seeds[0], None)
    assert EpisodeSettings(suite_id="RSB-Math-10", seeds=seeds, label="p", instruction_mode=COUNTERFACTUAL,
                           variants=10).variants == 10
    with pytest.raises(ValueError, match="2..4"):
        EpisodeSettings(suite_id=SUITE, seeds=seeds, label="p", instruction_mode=COUNTERFACTUAL, variants=5)
    with pytest.raises(ValueError, match="counterfactual"):
        EpisodeSettings(suite_id=SUITE, seeds=seeds, label="p", variants=2)

    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path) as w:  # a run stopped after five variants
        for seed, k in settings.episodes()[:5]:
            w.write(record(seed, k, k, k))
    asked = []

    def run(todo, write):
        asked.extend(todo)
        for seed, k in todo:
            write(record(seed, k, k, k))

    records = drive(settings, path, run, progress=False)
    assert asked == settings.episodes()[5:] and len(records) == 12
    assert sorted(record_episode(r) for r in read_records(path)) == sorted(settings.episodes())
    asked.clear()
    drive(settings, path, run, progress=False)
    assert asked == []


def test_blind_draws_follow_and_switch_at_chance_and_leftmost_like_draws_stick():
    """The blind baseline draws afresh in every variant (variant 0 keeps the protocol's draw): its
    choices over many scenes follow at 1/N and switch at 1 - 1/N (physics: it grasps what it draws,
    tests/evaluation/test_counterfactual_physics.py)."""
    from rsb_maniskill.semantic import EpisodeSampler
    from rsb_maniskill.semantic import counterfactual as cf

    for suite in ("RSB-Direct-4", "RSB-Direct-10"):
        s = EpisodeSampler(suite, "test")
        recs = []
        for seed in eval_seeds(suite, 300):
            for v in cf.variants(s, seed):
                recs.append(record(seed, v.index, v.target, blind_target(seed, s.n_choices, v.index), suite))
        m = metrics(recs, suite)
        assert m.follow.low < m.chance_follow < m.follow.high, (suite, m.follow)
        assert m.switch.low < m.chance_switch < m.switch.high, (suite, m.switch)
        assert m.stuck.value < 0.05


def test_the_report_has_the_section(tmp_path):
    from rsb_maniskill.reporting.page import build_html
    from rsb_maniskill.reporting.summary import results_from_records
    from rsb_maniskill.reporting.writer import write_report

    recs = scenes(lambda rng, t, pick: t, n_scenes=5) + scenes(lambda rng, t, pick: pick, n_scenes=5, n=10,
                                                               suite="RSB-Math-10")
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    summary = json.loads(paths["json"].read_text())
    assert summary["counterfactual"]["rows"]["p (counterfactual)"][SUITE]["follow"]["value"] == 1.0
    md = paths["markdown"].read_text()
    assert "### Counterfactual scenes: p (counterfactual)" in md and "| **Pooled** |" in md
    assert paths["png:counterfactual"].read_bytes()[:4] == b"\x89PNG"
    csv_lines = paths["csv:counterfactual"].read_text().splitlines()
    assert len(csv_lines) == 4 and csv_lines[0].startswith("row,suite_id,n_choices")
    import jsonschema

    from rsb_maniskill.reporting.results import SCHEMA_FILE

    results = json.loads(paths["results"].read_text())  # the shared scores: no counterfactual row
    jsonschema.validate(results, json.loads(SCHEMA_FILE.read_text()))
    assert results["rows"] == []
    page = build_html(recs, tmp_path)
    assert '<section id="counterfactual">' in page and "data:image/png;base64," in page
    assert '<section id="counterfactual">' not in build_html([{**r, "instruction_mode": "normal"} for r in recs],
                                                            tmp_path)


def test_one_instruction_harnesses_refuse_the_mode_in_one_line():
    with pytest.raises(ValueError, match="under rsb eval only") as err:
        check_ablation_mode(COUNTERFACTUAL, "the LeRobot env")
    assert "\n" not in str(err.value)
    check_ablation_mode("shuffled", "vla-eval")
    with pytest.raises(ValueError, match="must be one of"):
        check_ablation_mode("loud", "vla-eval")
    from rsb_maniskill.integrations.lerobot_env import RSBLeRobotEnv

    with pytest.raises(ValueError, match="counterfactual"):
        RSBLeRobotEnv("RSB-Direct-4", instruction_mode=COUNTERFACTUAL)


def test_parallel_envs_run_the_variants_as_one_env_does():
    """batched_loop resets each env with its own variant (a list of indices) and records it as the
    one-env loop does, episode for episode."""
    import types

    from rsb_maniskill.evaluation.runner import batched_loop, episode_loop

    from fake_envs import FakeBatchedEnv, FakeRSBEnv, ScriptedPolicy, _strip

    class VariantEnv(FakeRSBEnv):
        def reset(self, seed=None, options=None):
            k = (options or {}).get("variant")
            self.episode_variants = [None if k is None else types.SimpleNamespace(index=k, kind=f"kind{k}")]
            self.k = k
            return super().reset(seed=seed)

        def get_language_instruction(self):
            return [f"question {self.seed}, variant {self.k}"]

    class VariantBatchedEnv(FakeBatchedEnv):
        def __init__(self, num_envs):
            super().__init__(num_envs)
            self.envs = [VariantEnv() for _ in range(num_envs)]

        @property
        def episode_variants(self):
            return [e.episode_variants[0] for e in self.envs]

        def reset(self, seed=None, options=None):
            ks = options["variant"]
            ks = ks if isinstance(ks, list) else [ks] * self.num_envs
            out = [e.reset(seed=s, options={"variant": k}) for e, s, k in zip(self.envs, seed, ks)]
            return self._cat([o for o, _ in out]), self._cat([i for _, i in out])

    seeds = eval_seeds(SUITE, 3)
    settings = EpisodeSettings(suite_id=SUITE, seeds=seeds, label="p", instruction_mode=COUNTERFACTUAL, variants=3)
    single = []
    episode_loop(VariantEnv(), ScriptedPolicy(), settings, settings.episodes(), single.append)
    assert [(r["seed"], r["variant"], r["variant_kind"]) for r in single] == [
        (s, k, f"kind{k}") for s in seeds for k in range(3)]
    assert all(r["instruction"].endswith(f"variant {r['variant']}") for r in single)
    for num_envs in (2, 4):
        batched = []
        batched_loop(VariantBatchedEnv(num_envs), [ScriptedPolicy() for _ in range(num_envs)], settings,
                     settings.episodes(), batched.append)
        assert sorted(_strip(batched), key=lambda r: (r["seed"], r["variant"])) == _strip(single)


@pytest.mark.parametrize("argv, message", [
    (["--variants", "3"], "--variants sets the counterfactual variants per scene: add --instruction counterfactual"),
    (["--instruction", "counterfactual", "--variants", "5"], "--variants 5 on RSB-Math-4: counterfactual variants: "
                                                              "K must be 2..4"),
])
def test_eval_refuses_bad_variants_in_one_line(argv, message, tmp_path, capsys):
    from rsb_maniskill.cli import main

    assert main(["eval", "oracle", "--suites", SUITE, "-n", "1", "--out", str(tmp_path / "r"), "-q", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r" / "episodes.jsonl").exists()
