"""Per-category tables: the semantic engine's categories (from the spec and its pool question, never
the instruction), the runner writing them into records, the tables counted from records (TSR, nSG,
first grasp right, small cells flagged), and records written before categories existed."""
from __future__ import annotations

import csv
import json
import os
import re

import pytest

from rsb_maniskill.evaluation.records import CATEGORIES_FIELD, LEFT_RANK_FIELD
from rsb_maniskill.evaluation.runner import EpisodeSettings, episode_loop
from rsb_maniskill.reporting.sections.categories import (
    SMALL_CELL,
    SMALL_MARK,
    categories_markdown,
    categories_rows,
    category_cell,
    category_tables,
)
from rsb_maniskill.reporting.summary import results_from_records
from rsb_maniskill.reporting.writer import write_report
from rsb_maniskill.semantic import EpisodeSampler, clear_cache
from rsb_maniskill.semantic import categories as cat
from rsb_maniskill.semantic.gsm8k import question_from_row, reasoning_steps

from fake_envs import FakeRSBEnv, ScriptedPolicy

SEEDS = range(10_000_000, 10_000_200)
REAL_DATA_DIR = os.environ.get("RSB_DATA_DIR")  # read before a fixture points it at the test fixtures


# ------------------------------------------------------------ the semantic engine's categories
def test_bins():
    assert [cat.steps_bin(k) for k in (0, 1, 2, 4, 5, 9)] == ["0-1", "0-1", "2", "4", "5+", "5+"]
    assert [cat.answer_size_bin(v) for v in (7, -7, 42, 999, 1000, 123456)] == [
        "1 digit", "1 digit", "2 digits", "3 digits", "4+ digits", "4+ digits"]
    assert cat.answer_size_bin(12345, decimals=2) == "3 digits"  # 123.45
    assert cat.value_order(["5+", "0-1", "3", "2"]) == ["0-1", "2", "3", "5+"]
    assert cat.value_order(["10", "9", "minus", "plus"]) == ["9", "10", "minus", "plus"]  # by number, then name
    assert cat.value_label(cat.SOURCE, "mmlu_pro") == "MMLU-Pro"
    assert cat.value_label(cat.TEMPLATE, "21") == "template 21"


def test_gsm8k_steps_are_counted_before_the_annotations_are_stripped():
    answer = "He buys 3*2=<<3*2=6>>6 pens.\nThen 6+4=<<6+4=10>>10.\n#### 10"
    q = question_from_row({"question": "How many?", "answer": answer, "origin": "t, line 1"})
    assert reasoning_steps(answer) == 2 and q.steps == 2 and "<<" not in q.solution
    assert reasoning_steps("No computation here.\n#### 3") == 0


def test_math_categories_come_from_the_question_not_the_instruction():
    s = EpisodeSampler("RSB-Math-4", "test", instructions="unseen")
    for seed in SEEDS[:50]:
        spec = s.episode(seed)
        q = s.question(spec.question_id)
        got = s.categories(spec)
        assert got == {"suite_kind": "question", "template": str(spec.template_id), "operator": q.group,
                       "answer_size": cat.answer_size_bin(q.value)}
        assert q.group in ("plus", "minus", "times") and got["answer_size"] in ("2 digits", "3 digits")


def test_direct_suites_have_template_and_kind_only():
    s = EpisodeSampler("RSB-Direct-10", "test", instructions="unseen")
    spec = s.episode(SEEDS[0])
    assert s.categories(spec) == {"suite_kind": "direct", "template": str(spec.template_id)}


def test_pools_carry_the_new_fields(question_data):
    """Pools live in memory only (pools._POOLS, lru caches): a pool built by this code has steps on
    every GSM8K question and MMLU-Pro's category on every MMLU-Pro question."""
    clear_cache()
    hard = EpisodeSampler("RSB-HardMath-4", "test", data_dir=question_data)
    assert all(q.steps is not None for q in hard.pool.questions)
    general = EpisodeSampler("RSB-General-10", "test", data_dir=question_data)
    mmlu = [q for q in general.pool.questions if q.source == "mmlu_pro"]
    assert mmlu and all(q.category for q in mmlu)
    seeds = range(0, general.num_questions, max(1, general.num_questions // 60))  # questions across the pool
    sources = {general.categories(general.episode(seed)).get("source") for seed in seeds}
    assert sources == {"commonsense", "mmlu_pro"}
    for seed in seeds:
        spec = general.episode(seed)
        got = general.categories(spec)
        q = general.question(spec.question_id)
        assert ("mmlu_category" in got) == (q.source == "mmlu_pro")
        if q.source == "mmlu_pro":
            assert got["mmlu_category"] == q.category  # MMLU-Pro's category, also where group is MMLU's subject


@pytest.mark.data
def test_real_pools_categories():
    """GSM8K test: steps 0-8 (18 solutions without annotations); MMLU-Pro: its 14 categories."""
    if not REAL_DATA_DIR:
        pytest.skip("RSB_DATA_DIR is not set (CI sets it to the real GSM8K / MMLU-Pro)")
    clear_cache()
    hard = EpisodeSampler("RSB-HardMath-10", "test", data_dir=REAL_DATA_DIR)
    assert {q.steps for q in hard.pool.questions} == set(range(9))
    general = EpisodeSampler("RSB-General-4", "test", data_dir=REAL_DATA_DIR)
    cats = {q.category for q in general.pool.questions if q.source == "mmlu_pro"}
    assert len(cats) == 14 and "law" in cats
    taken_from_mmlu = [q for q in general.pool.questions if q.source == "mmlu_pro" and q.group != q.category]
    assert taken_from_mmlu  # group keeps MMLU's subject; the category rides beside it


# ------------------------------------------------------------ the runner writes them
class CategorizedEnv(FakeRSBEnv):
    """The fake env with RSB-Math-4's real specs and the task's ``episode_categories``."""

    sampler = EpisodeSampler("RSB-Math-4", "test", instructions="unseen")

    def reset(self, seed=None, options=None):
        out = super().reset(seed=seed, options=options)
        self.episode_specs = [self.sampler.episode(seed)]
        return out

    def episode_categories(self, spec):
        return self.sampler.categories(spec)


def test_the_runner_writes_categories_and_positions():
    env, records = CategorizedEnv(), []
    seeds = list(SEEDS[:4])
    episode_loop(env, ScriptedPolicy(), EpisodeSettings(suite_id="RSB-Math-4", seeds=seeds, label="p"), seeds,
                 records.append)
    for r in records:
        spec = env.sampler.episode(r["seed"])
        assert r[CATEGORIES_FIELD] == env.sampler.categories(spec)
        assert sorted(r[LEFT_RANK_FIELD]) == [0, 1, 2, 3]
    plain = []  # a task without episode_categories: no categories, nothing breaks
    episode_loop(FakeRSBEnv(), ScriptedPolicy(), EpisodeSettings(suite_id="RSB-Math-4", seeds=seeds, label="p"),
                 seeds, plain.append)
    assert all(CATEGORIES_FIELD not in r and LEFT_RANK_FIELD not in r for r in plain)


# ------------------------------------------------------------ the tables
def _record(i: int, suite: str, cats: dict, ok: bool, grasp: int, target: int = 0, policy: str = "p") -> dict:
    return {"policy": policy, "suite_id": suite, "seed": i, "instruction_mode": "normal", "success": ok,
            "grasped_any": grasp >= 0, "grasped_correct": grasp == target, "first_grasped": grasp,
            "target_block": target, CATEGORIES_FIELD: cats}


def _math(i: int, op: str, ok: bool, grasp: int) -> dict:
    return _record(i, "RSB-Math-4", {"suite_kind": "question", "template": "20", "operator": op,
                                     "answer_size": "2 digits"}, ok, grasp)


def test_a_cell_counts_tsr_nsg_and_first_grasp_right():
    recs = [_math(i, "plus", i < 30, 0 if i < 35 else (1 if i < 45 else -1)) for i in range(50)]
    c = category_cell(recs, 4)
    assert (c.n_episodes, c.n_grasped, c.n_success, c.n_first, c.n_first_right) == (50, 45, 30, 45, 35)
    assert c.tsr.value == pytest.approx(0.6) and c.first_right.value == pytest.approx(35 / 45)
    assert c.nsg.value == pytest.approx((30 / 45 - 0.25) / 0.75) and c.nsg.low < c.nsg.value < c.nsg.high
    assert not c.small and category_cell(recs[:SMALL_CELL - 1], 4).small


def test_tables_split_a_suite_by_its_dimensions_and_pool_suite_kinds():
    recs = [_math(i, ("plus", "minus", "times")[i % 3], i % 3 == 0, 0 if i % 3 == 0 else 1) for i in range(90)]
    recs += [_record(1000 + i, "RSB-Direct-4", {"suite_kind": "direct", "template": "8"}, True, 0) for i in range(30)]
    t = category_tables(recs)["p"]
    ops = t.suites["RSB-Math-4"]["operator"]
    assert list(ops) == ["minus", "plus", "times"] and ops["plus"].tsr.value == 1.0 and ops["minus"].tsr.value == 0.0
    assert "suite_kind" not in t.suites["RSB-Math-4"]  # one value per suite: pooled instead
    assert {k: c.n_episodes for k, c in t.kinds.items()} == {("question", 4): 90, ("direct", 4): 30}
    md = categories_markdown(category_tables(recs))
    assert "### p on RSB-Math-4: by category (%)" in md and "| **Operator** |" in md
    assert "### p: Direct vs question suites (%)" in md and "| Direct (target named), 4 choices | 30 |" in md
    plus = next(line for line in md.splitlines() if line.startswith("| plus |"))
    assert plus.startswith("| plus | 30 | 100.0 [") and plus.endswith(" | 30 |")


def test_small_cells_are_marked_not_hidden():
    recs = [_math(i, "plus" if i < 25 else "times", True, 0) for i in range(30)]
    md = categories_markdown(category_tables(recs))
    assert re.search(r"^\| plus \| 25 \|", md, re.M)
    assert re.search(rf"^\| times \| 5{SMALL_MARK} \|", md, re.M) and f"fewer than {SMALL_CELL}" in md
    rows = categories_rows(category_tables(recs))
    assert {(r["value"], r["small"]) for r in rows if r["dimension"] == "operator"} == {("plus", False),
                                                                                       ("times", True)}


def test_each_rate_is_greyed_by_its_own_denominator():
    """Issue 49: a 100-episode cell with 3 grasps has an nSG over 3 grasps: marked (and greyed on the
    page), while its TSR over 100 episodes is not."""
    from rsb_maniskill.reporting.blocks import to_html
    from rsb_maniskill.reporting.sections.categories import categories_blocks

    recs = [_math(i, "plus", i < 2, 0 if i < 3 else -1) for i in range(100)]
    cell = category_tables(recs)["p"].suites["RSB-Math-4"]["operator"]["plus"]
    assert cell.n_episodes == 100 and cell.n_grasped == 3
    assert cell.small_rates() == {"tsr": False, "nsg": True, "first_right": True}
    md = categories_markdown(category_tables(recs))
    line = next(x for x in md.splitlines() if x.startswith("| plus |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert not cells[1].endswith(SMALL_MARK) and not cells[2].endswith(SMALL_MARK)  # episodes, TSR
    assert cells[3].endswith(SMALL_MARK) and cells[4].endswith(SMALL_MARK)  # nSG, first grasp right
    page = to_html(categories_blocks(category_tables(recs)))
    row = re.search(r"<tr><td>plus</td>(.*?)</tr>", page)[1]
    assert re.findall(r"<td( class=\"small\")?>", row) == ["", "", ' class="small"', ' class="small"', ""]
    rows = categories_rows(category_tables(recs))
    plus = next(r for r in rows if r["value"] == "plus" and r["dimension"] == "operator")
    assert (plus["small"], plus["small_nsg"], plus["small_tsr"]) == (False, True, False)


def test_old_records_without_categories_are_said_and_skipped(tmp_path):
    old = [{k: v for k, v in _math(i, "plus", True, 0).items() if k != CATEGORIES_FIELD} for i in range(10)]
    tables = category_tables(old)
    assert tables["p"].suites == {} and tables["p"].n_without == 10
    assert "carry no categories" in categories_markdown(tables)
    paths = write_report(results_from_records(old), tmp_path, records=old)
    summary = json.loads(paths["json"].read_text())
    assert "carry no categories" in summary["categories"]["note"] and "csv:categories" not in paths
    mixed = old + [_math(100 + i, "minus", False, 1) for i in range(30)]
    md = categories_markdown(category_tables(mixed))
    assert "| minus | 30 |" in md and "Records without categories, left out: p (10)" in md


def test_write_report_writes_the_categories_section_and_csv(tmp_path):
    recs = [_math(i, ("plus", "minus")[i % 2], i % 2 == 0, 0 if i % 2 == 0 else 2) for i in range(40)]
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    summary = json.loads(paths["json"].read_text())
    cell = summary["categories"]["rows"]["p"]["suites"]["RSB-Math-4"]["operator"]["plus"]
    assert cell["n_episodes"] == 20 and cell["tsr"]["value"] == 1.0 and cell["first_right"]["value"] == 1.0
    rows = list(csv.DictReader(open(paths["csv:categories"])))
    assert {(r["dimension"], r["value"]) for r in rows} >= {("operator", "plus"), ("operator", "minus"),
                                                           ("template", "20"), ("suite_kind", "question")}
    assert "by category" in paths["markdown"].read_text()


def test_one_test_across_each_dimension_holm_corrected():
    """Issue 49: TSR 90 % on plus against 10 % on times is a difference that survives Holm's correction;
    the answer sizes, equal in rate, show none; every adjusted p is at least its raw p."""
    from rsb_maniskill.reporting.sections.categories import FAMILY_ALPHA, categories_json, dimension_tests

    recs = [_math(i, "plus" if i < 60 else "times", (i % 10 < 9) if i < 60 else (i % 10 < 1), 0)
            for i in range(120)]
    for r in recs:  # answer size independent of success: alternate blocks of ten, each with the same outcomes
        r[CATEGORIES_FIELD] = {**r[CATEGORIES_FIELD], "answer_size": "2 digits" if r["seed"] // 10 % 2 else "3 digits"}
    tests = {t.dimension: t for t in dimension_tests(category_tables(recs))}
    assert tests["operator"].differs and tests["operator"].p_holm < FAMILY_ALPHA
    assert not tests["answer_size"].differs and tests["answer_size"].p > 0.5
    assert all(t.p_holm >= t.p for t in tests.values() if t.p is not None)
    assert tests["template"].p is None  # one template: not tested
    md = categories_markdown(category_tables(recs))
    assert "operator: TSR differs" in md and "answer size: no difference shown" in md
    js = categories_json(category_tables(recs))
    assert {t["dimension"]: t["differs"] for t in js["dimension_tests"]}["operator"] is True
