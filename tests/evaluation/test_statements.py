"""The text channel: policies that return {"actions", "text"} (one env, parallel envs, over the
websocket), the record fields it gives, and the paper's Table 5 counted from them (no physics)."""
from __future__ import annotations

import numpy as np
import pytest

from rsb_maniskill.evaluation.runner import EpisodeSettings, batched_loop, episode_loop
from rsb_maniskill.evaluation.statements import MAX_TEXT_CHARS, EpisodeText, reasoning_following, talks
from rsb_maniskill.policies.interface import PerEnvPolicies, split_output, split_outputs
from rsb_maniskill.semantic import EpisodeSampler

from fake_envs import OUTCOMES, SUITE, FakeBatchedEnv, FakeRSBEnv, ScriptedPolicy

SEEDS = [10_000_000 + i for i in range(16)]
SAMPLER = EpisodeSampler(SUITE, "test", instructions="unseen")


class SpecEnv(FakeRSBEnv):
    """The fake env with the real episode specs of RSB-Math-4 (outcomes still scripted by seed % 4)."""

    def reset(self, seed=None, options=None):
        out = super().reset(seed=seed, options=options)
        self.episode_specs = [SAMPLER.episode(seed)]
        return out


class SpecBatchedEnv(FakeBatchedEnv):
    def __init__(self, num_envs):
        super().__init__(num_envs)
        self.envs = [SpecEnv() for _ in range(num_envs)]


def said_for(spec, seed: int) -> str | None:
    """Seed // 4 % 4 -> what the policy says: the right option, a wrong one, nothing it can parse, no text."""
    kind = (seed // 4) % 4
    wrong = spec.letters[(spec.answer_slot + 1) % spec.n_choices]
    return (f"I compute the answer: option {spec.correct_letter}.", f"It is option {wrong}.", "Hmm.", None)[kind]


class Talker(ScriptedPolicy):
    """States an option with every chunk (the same text each time), reading the answer from the env."""

    def __init__(self, env):
        super().__init__()
        self.env = env

    def act(self, obs):
        chunk = super().act(obs)
        text = said_for(self.env.episode_specs[0], self.env.seed)
        return chunk if text is None else {"actions": chunk, "text": text}


def test_policy_outputs_are_split_and_checked():
    chunk = np.zeros((2, 14))
    assert split_output(chunk)[1] is None and split_output({"actions": chunk, "text": "x"})[1] == "x"
    with pytest.raises(ValueError, match="without 'actions'"):
        split_output({"text": "x"})
    with pytest.raises(ValueError, match="must be a str"):
        split_output({"actions": chunk, "text": 3})
    assert split_outputs({"actions": [chunk, chunk], "text": ["a", None]}, 2)[1] == ["a", None]
    with pytest.raises(ValueError, match="list of 2"):
        split_outputs({"actions": [chunk, chunk], "text": "a"}, 2)
    # per-env policies: a mapping only when one of them talked
    out = PerEnvPolicies([ScriptedPolicy(), ScriptedPolicy()]).act_batch({"agent": {"qpos": np.zeros((2, 14))}}, [0, 1])
    assert isinstance(out, list) and len(out) == 2


def test_episode_text_is_bounded_and_parsed_whole():
    spec = SAMPLER.episode(SEEDS[0])
    said = EpisodeText()
    assert said.fields(spec) == {}  # never talked: no fields at all
    said.add(None)
    assert said.fields(spec) == {}
    long = "x" * (MAX_TEXT_CHARS + 500)
    for text in ("", long, long, f"so option {spec.correct_letter}"):  # a repeat is kept once
        said.add(text)
    fields = said.fields(spec)
    assert len(fields["text"]) == MAX_TEXT_CHARS and fields["text_chars"] == len(long) + 1 + len("so option A")
    assert fields["stated_letter"] == spec.correct_letter  # parsed from the whole text, past the cut


def _check_talking_records(records):
    by_seed = {r["seed"]: r for r in records}
    assert sorted(by_seed) == SEEDS
    for seed, r in by_seed.items():
        spec = SAMPLER.episode(seed)
        kind = (seed // 4) % 4
        if kind == 3:
            assert "text" not in r and "stated_letter" not in r
            continue
        assert r["text"] == said_for(spec, seed)  # the same text every chunk: kept once
        expected = (spec.correct_letter, spec.letters[(spec.answer_slot + 1) % 4], None)[kind]
        assert r["stated_letter"] == expected


def test_one_env_records_keep_what_the_policy_said(tmp_path):
    env = SpecEnv()
    records = []
    episode_loop(env, Talker(env), EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="talker"), SEEDS,
                 records.append)
    _check_talking_records(records)
    assert talks(records)
    # the quiet policy's records have no text fields
    quiet = []
    episode_loop(SpecEnv(), ScriptedPolicy(), EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="q"), SEEDS,
                 quiet.append)
    assert not talks(quiet) and not any("text" in r for r in quiet)


@pytest.mark.parametrize("num_envs", [1, 3])
def test_parallel_envs_keep_each_envs_text(num_envs):
    env = SpecBatchedEnv(num_envs)
    records = []
    settings = EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="talker")
    batched_loop(env, [Talker(e) for e in env.envs], settings, SEEDS, records.append)
    _check_talking_records(records)


def test_table5_counts(tmp_path):
    env = SpecEnv()
    records = []
    episode_loop(env, Talker(env), EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="talker"), SEEDS,
                 records.append)
    t = reasoning_following(records, SUITE)
    # seed % 4 is the outcome, seed // 4 % 4 what was said: 4 episodes of each pair of the 16
    assert (t.n_episodes, t.n_grasped, t.n_grasped_failed) == (16, 12, 8)
    assert t.failures == {"not_placed": 4, "stated_wrong": 1, "stated_right": 1, "no_statement": 2}
    assert t.failure_rates()["stated_right"].value == 1 / 8
    assert t.crossing["right/right"] == 2 and t.crossing["none/wrong"] == 2 and sum(t.crossing.values()) == 12
    assert t.n_stated_right == 4 and t.stated_right_rate().low < 0.25 < t.stated_right_rate().high
    assert {OUTCOMES[s % 4] for s in SEEDS} == set(OUTCOMES)
    with pytest.raises(ValueError, match="passed to"):
        reasoning_following(records, "RSB-Math-10")


class EnvTalker:
    """Both forms, over the wire: says "option <letter of its env index>" with every chunk."""

    def reset(self, instruction, obs):
        pass

    def act(self, obs):
        return {"actions": np.zeros((3, 14), np.float32), "text": "option A"}

    def reset_batch(self, instructions, obs):
        pass

    def reset_envs(self, instructions, obs, envs):  # served: the batched form (one client here: slot = env index)
        pass

    def act_batch(self, obs, envs):
        return {"actions": np.zeros((len(envs), 3, 14), np.float32), "text": [f"option {'ABCD'[e]}" for e in envs]}


@pytest.mark.timeout(60)
@pytest.mark.parametrize("batch", [True, False])
def test_text_over_the_websocket(batch):
    from rsb_maniskill.policies.remote.client import RemotePolicy
    from rsb_maniskill.policies.remote.server import PolicyServer

    with PolicyServer(EnvTalker(), host="127.0.0.1", port=0) as server:
        with RemotePolicy("127.0.0.1", server.port, batch=batch, connect_timeout=10, request_timeout=10) as client:
            client.reset("q", {})
            out = client.act({"agent": {"qpos": np.zeros(14, np.float32)}})
            assert out["text"] == "option A" and out["actions"].shape == (3, 14)
            env, records = SpecBatchedEnv(3), []
            batched_loop(env, client, EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="remote"), SEEDS,
                         records.append)
    for r in records:
        i = SEEDS.index(r["seed"]) % 3  # env i of its wave
        assert r["stated_letter"] == ("ABCD"[i] if batch else "A") and r["text"].startswith("option")


def test_table5_in_the_summaries_and_the_report(tmp_path):
    import csv
    import json

    from rsb_maniskill.reporting.summary import results_from_records
    from rsb_maniskill.reporting.writer import write_html_report, write_report

    records = []
    for label, policy in (("talker", Talker), ("quiet", lambda env: ScriptedPolicy())):
        env = SpecEnv()
        episode_loop(env, policy(env), EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label=label), SEEDS,
                     records.append)
    paths = write_report(results_from_records(records), tmp_path, records=records)
    summary = json.loads(paths["json"].read_text())
    table = summary["reasoning_following"]
    assert list(table) == ["talker"]  # the quiet policy has no statements to count
    cell = table["talker"][SUITE]
    assert cell["failures"]["stated_right"] == 1 and cell["n_grasped_failed"] == 8
    assert cell["failure_rates"]["not_placed"]["value"] == 0.5 and cell["failure_rates"]["not_placed"]["low"] < 0.5
    md = paths["markdown"].read_text()
    assert f"### Reasoning following on {SUITE} (%, paper Table 5)" in md
    assert "| Stated right, wrong target | 12.5 [" in md and "| Grasped-but-failed episodes (count) | 8 |" in md
    rows = list(csv.DictReader(open(paths["csv:reasoning"])))
    assert {r["part"] for r in rows} == {"failures", "crossing", "stated"}
    got = next(r for r in rows if r["part"] == "failures" and r["cell"] == "no_statement")
    assert (got["count"], got["n"], float(got["value"])) == ("2", "8", 0.25)
    page = write_html_report(tmp_path, records=records).read_text()
    assert 'id="reasoning"' in page and "Stated right, wrong target" in page
    assert '"said":"It is option' in page and '"said":null' in page  # the cards carry the text
