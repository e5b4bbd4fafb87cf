"""JSON-lines episode records: durable appends, torn last lines, resume gives the same summary."""
from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.evaluation.records import RECORD_FIELDS, validate_record
from rsb_maniskill.evaluation.store import RecordWriter, completed_seeds, read_records, repair_tail, safe_name
from rsb_maniskill.reporting.summary import results_from_records, summary_dict


def episode(seed, suite="RSB-Math-4", policy="p", mode="normal"):
    """A full record whose outcome is a deterministic function of the seed."""
    rng = random.Random(seed)
    grasped = rng.random() < 0.8
    correct = grasped and rng.random() < 0.4
    success = correct and rng.random() < 0.9
    return {
        "suite_id": suite, "seed": seed, "question_id": seed % 37, "instruction": f"question {seed}: pick ...",
        "instruction_mode": mode, "target_block": seed % 4, "correct_letter": "ABCD"[seed % 4],
        "first_grasped": (seed % 4 if correct else (seed + 1) % 4) if grasped else -1,
        "grasped_any": grasped, "grasped_correct": correct, "placed_correct": success,
        "placed_wrong": grasped and not correct and rng.random() < 0.5, "success": success,
        "steps": 100 + seed % 50, "policy": policy,
    }


SEEDS = [10_000_000 + i for i in range(100)]


def test_write_read_roundtrip_with_numpy_values(tmp_path):
    path = tmp_path / "sub" / "episodes.jsonl"
    r = episode(1) | {"extra_array": np.arange(3), "extra_scalar": np.float32(0.5), "flag": np.bool_(True)}
    with RecordWriter(path) as w:
        w.write(r)
    (back,) = read_records(path)
    assert back["extra_array"] == [0, 1, 2] and back["extra_scalar"] == 0.5 and back["flag"] is True
    assert {k: back[k] for k in RECORD_FIELDS} == {k: r[k] for k in RECORD_FIELDS}
    assert path.read_text().endswith("\n") and path.read_text().count("\n") == 1


def test_validate_record():
    with pytest.raises(ValueError, match="success"):
        validate_record({k: v for k, v in episode(0).items() if k != "success"})
    with pytest.raises(ValueError, match="instruction_mode"):
        validate_record(episode(0, mode="upside-down"))


def test_truncated_last_line_is_skipped(tmp_path):
    path = tmp_path / "e.jsonl"
    with RecordWriter(path) as w:
        for s in SEEDS[:3]:
            w.write(episode(s))
    text = path.read_text()
    path.write_text(text + json.dumps(episode(SEEDS[3]))[:40])  # killed mid-write
    with pytest.warns(UserWarning, match="truncated"):
        records = read_records(path)
    assert [r["seed"] for r in records] == SEEDS[:3]
    with pytest.warns(UserWarning):
        assert completed_seeds(path) == set(SEEDS[:3])


def test_complete_unterminated_last_line_is_kept(tmp_path):
    path = tmp_path / "e.jsonl"
    path.write_text(json.dumps(episode(SEEDS[0])) + "\n" + json.dumps(episode(SEEDS[1])))  # cut before "\n"
    assert completed_seeds(path) == set(SEEDS[:2])
    # The writer agrees with the reader: the record stays, and the next one starts on its own line.
    with RecordWriter(path) as w:
        w.write(episode(SEEDS[2]))
    assert [r["seed"] for r in read_records(path)] == SEEDS[:3]


def test_corrupt_middle_line_raises(tmp_path):
    path = tmp_path / "e.jsonl"
    path.write_text(json.dumps(episode(SEEDS[0])) + "\n{not json\n" + json.dumps(episode(SEEDS[1])) + "\n")
    with pytest.raises(ValueError, match=":2:"):
        read_records(path)


def test_repair_tail(tmp_path):
    path = tmp_path / "e.jsonl"
    assert repair_tail(path) is False  # missing file
    path.write_text('{"a": 1}\n{"b": ')
    assert repair_tail(path) is True and path.read_text() == '{"a": 1}\n'
    assert repair_tail(path) is False
    path.write_text('{"b": 2')  # torn single line, no newline at all
    assert repair_tail(path) is True and path.read_text() == ""


def test_completed_seeds_filters(tmp_path):
    path = tmp_path / "e.jsonl"
    with RecordWriter(path) as w:
        w.write(episode(1, suite="RSB-Math-4", policy="a"))
        w.write(episode(2, suite="RSB-Math-10", policy="a"))
        w.write(episode(3, suite="RSB-Math-4", policy="b"))
        w.write(episode(4, suite="RSB-Math-4", policy="a", mode="blank"))
    assert completed_seeds(path) == {1, 2, 3, 4}
    assert completed_seeds(path, suite_id="RSB-Math-4", instruction_mode="normal", policy="a") == {1}
    assert completed_seeds(path, instruction_mode="blank") == {4}
    assert completed_seeds(tmp_path / "missing.jsonl") == set()


def test_duplicates_keep_the_first(tmp_path):
    path = tmp_path / "e.jsonl"
    first = episode(5)
    dup = first | {"success": not first["success"]}
    with RecordWriter(path) as w:
        w.write(first)
        w.write(dup)
    assert read_records(path) == [first]
    assert len(read_records(path, unique=False)) == 2


def test_resume_after_kill_gives_the_same_summary(tmp_path):
    full = tmp_path / "full.jsonl"
    with RecordWriter(full) as w:
        for s in SEEDS:
            w.write(episode(s))

    # 60 episodes, then killed while writing the 61st: a torn last line.
    part = tmp_path / "resumed.jsonl"
    with RecordWriter(part) as w:
        for s in SEEDS[:60]:
            w.write(episode(s))
    with open(part, "a") as f:
        f.write(json.dumps(episode(SEEDS[60]))[:57])

    with pytest.warns(UserWarning):
        done = completed_seeds(part, "RSB-Math-4", "normal", "p")
    assert done == set(SEEDS[:60])
    with RecordWriter(part) as w:  # resume: only the seeds not recorded
        for s in SEEDS:
            if s not in done:
                w.write(episode(s))

    resumed = read_records(part)
    assert [r["seed"] for r in resumed] == SEEDS
    assert summary_dict(results_from_records(resumed)) == summary_dict(results_from_records(read_records(full)))
    # and the summary is not trivially equal: it changes if one outcome changes
    changed = read_records(full)
    changed[0] = changed[0] | {"success": not changed[0]["success"], "grasped_any": True}
    assert summary_dict(results_from_records(changed)) != summary_dict(results_from_records(resumed))


def test_safe_name_keeps_the_names_of_existing_labels():
    """One sanitiser for results directories, summary charts and videos: the names each of the four
    former ones gave these labels do not change."""
    assert safe_name("oracle") == "oracle"
    assert safe_name("my_policies:make_policy") == "my_policies_make_policy"  # results/<name> as before
    assert safe_name("pkg/sub.mod:Make") == "pkg_sub.mod_Make"
    assert safe_name("oracle (blank)") == "oracle_blank"  # summary_<row>.png as before
    assert safe_name("blindcam [camera=2]") == "blindcam_camera_2"
    assert safe_name("camera=2,noise=1") == "camera_2_noise_1"  # a video's perturbation suffix
    assert safe_name("???") == "policy"


def test_default_results_dir_is_made_and_named_from_the_label(tmp_path, monkeypatch):
    from rsb_maniskill.commands.eval_args import EvalError, results_dir

    monkeypatch.chdir(tmp_path)
    assert results_dir(None, "my_policies:make_policy") == Path("results/my_policies_make_policy")
    assert (tmp_path / "results/my_policies_make_policy").is_dir()
    assert results_dir(str(tmp_path / "mine"), "x") == tmp_path / "mine"
    (tmp_path / "file").write_text("")
    with pytest.raises(EvalError, match="cannot write to results directory"):
        results_dir(str(tmp_path / "file" / "sub"), "x")


def test_locked_writers_share_a_file_and_repair_a_torn_tail(tmp_path):
    """LeRobot's sub-envs append to one file from several writers (lock=True): each record whole,
    a torn last line (a killed writer) cut off first."""
    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path, lock=True) as a, RecordWriter(path, lock=True) as b:
        a.write(episode(0))
        with open(path, "a") as f:
            f.write('{"suite_id": "RSB-Ma')  # torn by a killed process
        b.write(episode(1))
        a.write(episode(2))
    assert [r["seed"] for r in read_records(path)] == [0, 1, 2]
    with pytest.raises(ValueError, match="lacks fields"):
        RecordWriter(path, lock=True).write({"seed": 3})
