"""Pinned episodes: every suite's episodes equal the digests of this benchmark version, the layout
digested without the simulator is the task's, and `rsb verify` tells which suite differs."""
from __future__ import annotations

import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import rsb_maniskill  # noqa: F401
from rsb_maniskill.audit import golden
from rsb_maniskill.cli import main
from rsb_maniskill.objects import layout
from rsb_maniskill.objects.family import get_family
from rsb_maniskill.semantic import EpisodeSampler
from rsb_maniskill.version import BENCHMARK, BENCHMARK_VERSION

from conftest import FIXTURE_DATA

REPO = Path(__file__).resolve().parents[2]
FIXTURE_GOLDEN = REPO / "tests" / "fixtures" / "golden_fixture.json"
FIX = "python scripts/pin_episodes.py --bump X.Y --note '...' (docs/versions.md: How to change episodes)"


def test_every_suite_gives_the_pinned_episodes(question_data):
    """Real data ($RSB_DATA_DIR, CI) against the package's golden file; the tests' fixture data
    against their own pinned digests."""
    path = FIXTURE_GOLDEN if question_data.resolve() == FIXTURE_DATA.resolve() else golden.GOLDEN_FILE
    pinned = golden.load(path)
    assert pinned["benchmark_version"] == BENCHMARK_VERSION, f"{path} pins another version: {FIX}"
    digests = golden.compute(data_dir=question_data)
    assert set(digests) == set(pinned["suites"]) and len(digests) == 16
    assert all(set(d) == {"eval", "train", "counterfactual"} for d in pinned["suites"].values())
    diff = golden.differences(digests, pinned)
    assert diff == {}, f"episodes changed ({diff}) without a new benchmark version: {FIX}"


def test_the_version_has_its_section_in_the_docs():
    doc = (REPO / "docs" / "versions.md").read_text()
    assert f"### {BENCHMARK} {BENCHMARK_VERSION}\n" in doc
    sections = re.findall(r"^### RSB-MS (\d+\.\d+)$", doc, re.M)
    assert sections[0] == BENCHMARK_VERSION, "the newest version's section comes first"
    assert golden.load()["benchmark"] == f"{BENCHMARK} {BENCHMARK_VERSION}"


def test_a_changed_episode_or_layout_changes_the_digest(monkeypatch):
    before = golden.suite_digests("RSB-Math-4")
    monkeypatch.setattr(layout, "ROWS_X", layout.ROWS_X + 1e-3)  # every cell 1 mm further: layout only
    moved = golden.suite_digests("RSB-Math-4")
    assert moved["eval"] != before["eval"] and moved["train"] != before["train"]
    assert golden.differences({"RSB-Math-4": moved}, {"suites": {"RSB-Math-4": before}}) == {
        "RSB-Math-4": ["eval", "train"]}
    assert moved["counterfactual"] == before["counterfactual"]  # a variant's layout is its scene's: pinned by eval
    assert golden.differences({"RSB-Math-4": before}, {"suites": {}}) == {
        "RSB-Math-4": ["eval", "train", "counterfactual"]}


def test_the_counterfactual_digest_pins_the_variants(monkeypatch):
    """Only the variants' digest moves when the variants do, and pinning a new kind of digest is an
    addition, not a change of the pinned episodes (the additive amendment of docs/versions.md)."""
    from rsb_maniskill.semantic import counterfactual

    before = golden.suite_digests("RSB-Direct-10")
    assert set(before) == {"eval", "train", "counterfactual"}
    monkeypatch.setattr(counterfactual, "SALT", "another stream")  # other targets for variants 1..K-1
    after = golden.suite_digests("RSB-Direct-10")
    assert (after["eval"], after["train"]) == (before["eval"], before["train"])
    assert after["counterfactual"] != before["counterfactual"]
    old = {"suites": {"RSB-Direct-10": {k: before[k] for k in ("eval", "train")}}}
    assert golden.differences({"RSB-Direct-10": before}, old) == {"RSB-Direct-10": ["counterfactual"]}
    assert golden.differences({"RSB-Direct-10": before}, old, new=False) == {}
    assert golden.additions({"RSB-Direct-10": before}, old) == {"RSB-Direct-10": ["counterfactual"]}
    assert golden.differences({"RSB-Direct-10": after}, {"suites": {"RSB-Direct-10": before}}, new=False) == {
        "RSB-Direct-10": ["counterfactual"]}
    assert golden.differences({"RSB-Direct-10": before}, {"suites": {}}, new=False) == {
        "RSB-Direct-10": ["eval", "train", "counterfactual"]}  # a new suite is no addition


@pytest.mark.parametrize("env_id", ["RSB-Math-10", "RSB-Direct-4-Objects"])
def test_the_layout_without_the_simulator_is_the_tasks(env_id):
    """objects.layout.episode_layouts == what the task places at reset(seed), seed by seed."""
    from rsb_maniskill.objects.family import split_env_id

    seeds = [0, 7, 10_000_003]
    env = gym.make(env_id, obs_mode="state", render_backend="none")
    base = env.unwrapped
    specs, placed = [], []
    for seed in seeds:
        env.reset(seed=seed)
        specs.append(base.episode_specs[0])
        placed.append((base.block_slot[0].numpy().copy(), base.pool.raw_poses()[0].numpy().copy()))
    env.close()
    cells, xy, yaw = layout.episode_layouts(get_family(split_env_id(env_id)[1]), [s.candidates for s in specs], seeds)
    for i, (slots, poses) in enumerate(placed):
        assert slots.tolist() == cells[i].tolist()
        np.testing.assert_allclose(poses[:, :2], xy[i], atol=1e-6)
        task_yaw = 2 * np.arctan2(poses[:, 6], poses[:, 3])  # wxyz quaternion about z
        np.testing.assert_allclose(np.angle(np.exp(1j * (task_yaw - yaw[i]))), 0.0, atol=1e-5)


def test_reseeding_draws_what_maniskills_batched_rng_draws():
    from mani_skill.envs.utils.randomization.batched_rng import BatchedRNG

    fam = get_family("objects")
    seeds = [3, 10_000_000, 2**31 - 5]
    cands = [EpisodeSampler("RSB-Math-4", targets="objects").episode(s).candidates for s in seeds]
    half = np.array([[fam.shape(k).half_extents for k in keys] for keys in cands], dtype=np.float32)
    expected = layout.place(BatchedRNG.from_seeds(seeds), fam.layout, half)
    for got, want in zip(layout.episode_layouts(fam, cands, seeds), expected):
        np.testing.assert_array_equal(got, want)


def test_rsb_verify_names_the_suite_that_differs(tmp_path, monkeypatch, capsys):
    assert main(["verify", "RSB-Math-4,RSB-Direct-10"]) == 0
    out = capsys.readouterr().out
    assert "RSB-Math-4 " in out and "RSB-Direct-10 " in out and out.count(" ok\n") == 2
    assert f"this install gives the episodes of {BENCHMARK} {BENCHMARK_VERSION}" in out
    tampered = golden.load()
    tampered["suites"]["RSB-Direct-10"]["train"] = "0" * 64
    path = tmp_path / "golden.json"
    path.write_text(json.dumps(tampered))
    monkeypatch.setattr(golden, "GOLDEN_FILE", path)
    assert main(["verify", "RSB-Math-4", "rsb_math_10blocks", "RSB-Direct-10"]) == 1
    out = capsys.readouterr().out
    assert re.search(r"RSB-Direct-10 +DIFFERS from RSB-MS [\d.]+ \(train episodes\)", out)
    assert re.search(r"RSB-Math-10 +ok", out) and "does NOT give the episodes of RSB-MS" in out
