"""Bias tables: where each candidate stands left to right (from the seed's layout, checked against the
head camera's image and the live scene), the chi-square verdicts on synthetic policies (a favourite
position is found even at chance TSR; a uniform choice is not called biased), the expected shares of
everyday objects, old records, and in physics the fixed-position reference policy ``leftmost``."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from rsb_maniskill.evaluation.positions import left_ranks, ranks_from_xyz
from rsb_maniskill.evaluation.records import LEFT_RANK_FIELD
from rsb_maniskill.reporting.sections.bias import (
    ALPHA,
    MIN_GRASPS,
    bias_markdown,
    bias_plots,
    bias_table,
    chi_square,
    p_text,
    position_column,
    position_label,
)
from rsb_maniskill.reporting.summary import results_from_records
from rsb_maniskill.reporting.writer import write_report
from rsb_maniskill.semantic import EpisodeSampler

SEEDS = range(10_000_000, 10_000_400)


def test_ranks_and_labels():
    # camera at (-0.05, 0, 0.62) looking down +x: +y is image left; of two candidates in one column
    # (same y) the nearer one looks further out
    xyz = np.array([[0.35, 0.27, 0.02], [0.30, -0.09, 0.02], [0.40, 0.09, 0.02], [0.30, 0.27, 0.02]])
    assert ranks_from_xyz(xyz) == [1, 3, 2, 0]
    assert [position_label(k, 4) for k in range(4)] == ["leftmost", "2nd from left", "3rd from left", "rightmost"]
    assert position_label(10, 12) == "11th from left" and position_column(0, 4) == "1 (leftmost)"
    assert position_column(2, 4) == "3" and position_column(9, 10) == "10 (rightmost)"


def test_ranks_are_a_permutation_independent_of_the_answer():
    s = EpisodeSampler("RSB-Math-10", "test", instructions="unseen")
    target_ranks = []
    for seed in SEEDS:
        spec = s.episode(seed)
        ranks = left_ranks(spec)
        assert sorted(ranks) == list(range(10))
        target_ranks.append(ranks[spec.target_block])
    counts = np.bincount(target_ranks, minlength=10)
    assert chi_square(counts, [len(SEEDS) / 10] * 10)[1] > ALPHA  # the answer sits anywhere


def test_p_text_and_chi_square_edges():
    assert [p_text(p) for p in (0.0001, 0.004, 0.42)] == ["p < 0.001", "p = 0.004", "p = 0.42"]
    assert chi_square([5, 4], [4.5, 4.5]) == (None, None)  # under MIN_GRASPS
    stat, p = chi_square([40, 0, 0, 0], [10, 10, 10, 10])
    assert stat == pytest.approx(120.0) and p < 1e-20
    # fewer than 5 expected per category (10 positions, 40 grasps): p simulated, seeded
    assert chi_square([40] + [0] * 9, [4] * 10)[1] < 0.001
    spread = [5, 4, 3, 4, 5, 3, 4, 4, 4, 4]
    _, p = chi_square(spread, [4] * 10)
    assert p > 0.9 and chi_square(spread, [4] * 10)[1] == p
    # categories expecting nothing (an object never met) are left out
    assert chi_square([10, 10, 0], [10, 10, 0]) == pytest.approx((0.0, 1.0))


def _records(policy: str, choose, suite: str = "RSB-Math-4", targets: str = "blocks", n: int = 200,
             seed0: int = SEEDS[0]) -> list[dict]:
    s = EpisodeSampler(suite, "test", instructions="unseen", targets=targets)
    rng = np.random.default_rng(0)
    out = []
    for seed in range(seed0, seed0 + n):
        spec = s.episode(seed)
        ranks = left_ranks(spec)
        g = choose(spec, ranks, rng)
        out.append({"policy": policy, "suite_id": suite if targets == "blocks" else f"{suite}-Objects",
                    "seed": seed, "instruction_mode": "normal", "first_grasped": g, "grasped_any": g >= 0,
                    "target_block": spec.target_block, "success": g == spec.target_block,
                    "grasped_correct": g == spec.target_block, LEFT_RANK_FIELD: ranks, "episode": spec.to_dict()})
    return out


def leftmost(spec, ranks, rng):
    return int(np.argmin(ranks))


def uniform(spec, ranks, rng):
    return int(rng.integers(spec.n_choices))


def test_a_favourite_position_shows_even_at_chance_tsr():
    recs = _records("favourite-left", leftmost) + _records("uniform", uniform)
    table = bias_table(recs)
    left, flat = table["favourite-left"]["RSB-Math-4"], table["uniform"]["RSB-Math-4"]
    results = results_from_records(recs)
    assert abs(results["favourite-left"]["RSB-Math-4"].tsr.value - 0.25) < 0.08  # TSR says nothing
    pos = left.axes["position"]
    assert pos.significant and pos.observed[0] == 200
    assert pos.verdict() == "prefers the leftmost block: 100 % of grasps, expected 25 %, p < 0.001"
    assert not left.axes["candidate"].significant  # its colours are the layout's: uniform
    for axis in ("position", "candidate"):
        assert not flat.axes[axis].significant and flat.axes[axis].verdict().startswith("no preference detected (p = ")
    assert "letter" not in left.axes and left.letter_is_candidate  # fixed colour map: A is always red
    md = bias_markdown(table)
    assert "| favourite-left | RSB-Math-4 | 200 | prefers the leftmost block: 100 % of grasps" in md
    assert "option A is the red block in every 4-choice episode" in md
    # the test among wrong first grasps: each of the 3 wrong candidates expected 1/3
    assert "| favourite-left, wrong grasps only | RSB-Math-4 | 147 | prefers the leftmost block: 100 % of grasps, " \
           "expected 33 %, p < 0.001" in md
    assert "| uniform, wrong grasps only | RSB-Math-4 | 144 | no preference detected" in md


def test_ten_candidates_and_few_grasps_are_still_tested():
    """40 grasps over 10 positions expect 4 each: p simulated, the favourite still found."""
    recs = _records("favourite-left", leftmost, suite="RSB-Math-10", n=40)
    recs += _records("uniform", uniform, suite="RSB-Math-10", n=40)
    table = bias_table(recs)
    assert table["favourite-left"]["RSB-Math-10"].axes["position"].verdict() == (
        "prefers the leftmost block: 100 % of grasps, expected 10 %, p < 0.001")
    assert not any(p.significant for p in table["uniform"]["RSB-Math-10"].axes.values())


def test_a_favourite_colour_shows_on_the_candidate_axis():
    def red(spec, ranks, rng):  # block 0 is the red block: 60 % of the time, else any
        return 0 if rng.random() < 0.6 else int(rng.integers(4))

    b = bias_table(_records("red-lover", red))["red-lover"]["RSB-Math-4"]
    assert b.axes["candidate"].significant and b.axes["candidate"].verdict().startswith("prefers the red block: ")
    assert not b.axes["position"].significant


def test_everyday_objects_expect_each_category_its_share_of_the_candidates():
    recs = _records("uniform", uniform, targets="objects", n=300)
    b = bias_table(recs)["uniform"]["RSB-Math-4-Objects"]
    cand = b.axes["candidate"]
    present = {}
    for r in recs:
        for name in r["episode"]["block_names"]:
            present[name] = present.get(name, 0) + 1
    assert dict(zip(cand.labels, cand.expected)) == pytest.approx({k: v / 4 for k, v in present.items()})
    assert not cand.significant and "letter" in b.axes and not b.letter_is_candidate  # letters are not objects
    assert "(% of first grasps; in brackets: expected)" in bias_markdown({"uniform": {"RSB-Math-4-Objects": b}})


def test_too_few_grasps_and_old_records(tmp_path):
    recs = _records("p", leftmost, n=MIN_GRASPS - 1)
    b = bias_table(recs)["p"]["RSB-Math-4"]
    pos = b.axes["position"]
    assert pos.p is None and pos.verdict() == f"too few grasps to test (n = {MIN_GRASPS - 1})"
    old = [{k: v for k, v in r.items() if k not in (LEFT_RANK_FIELD, "episode")} for r in _records("old", leftmost)]
    b = bias_table(old)["old"]["RSB-Math-4"]
    assert b.axes == {} and "without left-to-right ranks" in b.missing["position"]
    paths = write_report(results_from_records(old), tmp_path, records=old)  # never a crash
    assert "n/a: 200 of 200 records without left-to-right ranks" in paths["markdown"].read_text()
    no_grasp = [{**r, "first_grasped": -1, "grasped_any": False, "success": False} for r in recs]
    assert bias_table(no_grasp)["p"]["RSB-Math-4"].n_grasped == 0


def test_write_report_and_plot_data(tmp_path):
    recs = _records("favourite-left", leftmost, suite="RSB-Math-10", n=60)
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    summary = json.loads(paths["json"].read_text())
    pos = summary["bias"]["rows"]["favourite-left"]["RSB-Math-10"]["axes"]["position"]
    assert pos["significant"] and pos["observed"][0] == 60 and pos["verdict"].startswith("prefers the leftmost block")
    rows = list(csv.DictReader(open(paths["csv:bias"])))
    assert {r["axis"] for r in rows} == {"position", "candidate"} and len(rows) == 40
    assert {r["row"] for r in rows} == {"favourite-left", "favourite-left, wrong grasps only"}
    fig = bias_plots(bias_table(recs))[0]
    chart = fig["charts"][0]
    assert chart["axis"] == "position" and [b["short"] for b in chart["bars"]] == [str(k) for k in range(1, 11)]
    first = chart["bars"][0]
    assert first["share"] == 1.0 and chart["ymax"] == 1.0 and first["expected"] == pytest.approx(0.1)


# ------------------------------------------------------------ physics
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_ranks_match_the_head_camera_and_the_scene():
    """The ranks from the seed's layout order the blocks as the head camera's image and the live scene do."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401
    from rsb_maniskill.objects.family import BLOCK_COLORS

    env = gym.make("RSB-Math-4", obs_mode="rgb", split="test", instructions="unseen")
    try:
        for seed in SEEDS[:4]:
            obs, _ = env.reset(seed=seed)
            base = env.unwrapped
            spec = base.episode_specs[0]
            live = np.stack([base.candidate_actor(c).pose.p[0].cpu().numpy() for c in range(4)])
            img = obs["sensor_data"]["head_camera"]["rgb"][0].cpu().numpy().astype(float)
            columns = []
            for rgb in BLOCK_COLORS.values():  # mean image column of each block's colour
                mask = np.linalg.norm(img - 255 * np.array(rgb), axis=-1) < 90
                assert mask.sum() > 20
                columns.append(np.nonzero(mask)[1].mean())
            in_image = np.argsort(np.argsort(columns)).tolist()
            assert left_ranks(spec) == ranks_from_xyz(live) == in_image
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_leftmost_reference_policy_is_found_biased(tmp_path):
    """A short physics run of the fixed-position reference policy: the position verdict names the
    leftmost block; the candidate axis does not."""
    from rsb_maniskill.cli import main
    from rsb_maniskill.evaluation.store import read_records

    out = tmp_path / "r"
    assert main(["eval", "leftmost", "--suites", "RSB-Math-4", "-n", str(MIN_GRASPS), "--out", str(out), "-q"]) == 0
    records = read_records(out / "episodes.jsonl")
    b = bias_table(records)["leftmost"]["RSB-Math-4"]
    pos = b.axes["position"]
    assert b.n_grasped >= MIN_GRASPS - 1 and pos.significant, pos
    assert pos.verdict().startswith("prefers the leftmost block: ") and pos.observed[0] >= pos.n - 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["bias"]["rows"]["leftmost"]["RSB-Math-4"]["axes"]["position"]["significant"]


def test_a_policy_that_shuns_one_value_is_said_to_avoid_it():
    """Issue 49: a policy that never takes the red block and spreads over the others avoids red (the
    verdict named the most over-represented value "preferred" before)."""
    from rsb_maniskill.reporting.sections.bias import preference

    order = ("red block", "green block", "blue block", "yellow block")
    p = preference("candidate", dict(zip(order, (0, 40, 40, 40))), dict.fromkeys(order, 30.0),
                   {k: f"the {k}" for k in order}, order)
    assert p.significant and p.verdict().startswith("avoids the red block: 0 % of grasps, expected 25 %")
    q = preference("candidate", dict(zip(order, (60, 20, 20, 20))), dict.fromkeys(order, 30.0),
                   {k: f"the {k}" for k in order}, order)
    assert q.verdict().startswith("prefers the red block: 50 % of grasps")
