"""Fault injection, issue 60's second sweep: files, names, plugins.

A killed generate worker, a full disk (a real tmpfs), long and unicode names, plugins that hang, exit or
replace a built-in, a resume from other code, read-only folders, a killed merge, non-UTF-8 locales.
The shared runners and checks are tests/helpers/fault_runs.py; the first sweep and the reports' rows
are tests/acceptance/test_faults.py (one file each so that the test workers run them side by side)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Callable

import h5py
import numpy as np
import pytest
from fault_runs import (
    DEMO_FILE,
    EVAL,
    GENERATE,
    REPO,
    SUITE,
    TESTS,
    _demos,
    _env,
    _pair,
    _resume_dir,
    error_lines,
    lines,
    records,
    reference_demos,
    rsb,
    start,
    stray_files,
    tree,
    wait_until,
    workers_of,
)


@pytest.fixture(scope="module")
def demos_reference(tmp_path_factory) -> Path:
    return reference_demos(tmp_path_factory)


# ------------------------------------------------------------ second sweep: files, names, plugins


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_generate_with_one_worker_killed_keeps_its_demos_then_resumes(demos_reference, tmp_path):
    """kill -9 of one worker (not the command): no final file (whose counts would be the survivors'),
    the finished demos kept, one line on stderr; the same command ends as an uninterrupted run."""
    out = tmp_path / "demos"
    run = [*GENERATE, "--num-procs", "2", "--out", str(out)]
    proc = start(*run)
    workers: list[int] = []
    assert wait_until(lambda: len(workers.extend(workers_of(proc.pid)) or set(workers)) >= 2, proc), \
        proc.communicate()[1][-2000:]
    os.kill(workers[0], signal.SIGKILL)
    out_text, err_text = proc.communicate(timeout=240)
    assert "Traceback" not in err_text and "error" not in out_text, out_text + err_text[-2000:]
    if proc.returncode == 1:  # (0: the worker had finished its share as the signal came)
        errors = error_lines(err_text)
        assert len(errors) == 1 and errors[0].startswith("rsb generate: error: worker "), err_text[-2000:]
        assert "died before finishing its share (killed by SIGKILL)" in errors[0]
        assert "rerun the same command to continue" in errors[0]
        assert not (out / DEMO_FILE).exists() and not (out / DEMO_FILE).with_suffix(".json").exists()
    else:
        assert proc.returncode == 0, err_text[-2000:]
    res = rsb(*run)
    assert res.returncode == 0, res.stderr[-2000:]
    assert _demos(out / DEMO_FILE)[0] == _demos(demos_reference)[0]
    data = json.loads((out / DEMO_FILE).with_suffix(".json").read_text())
    with h5py.File(out / DEMO_FILE) as f:  # the counts the json states are those of the h5
        assert data["rsb"]["completed"] == len(data["episodes"]) == len(f.keys()) == 2
    assert stray_files(out) == []


@pytest.fixture
def small_disk(tmp_path) -> Callable[[str], Path]:
    """A tmpfs of a given size at tmp_path/disk (resized by calling again): a real full disk.
    Mounting needs root (CI and this project's machines run tests as root); skipped elsewhere."""
    disk = tmp_path / "disk"
    disk.mkdir()

    def mount(size: str) -> Path:
        opts = f"size={size}" if not os.path.ismount(disk) else f"remount,size={size}"
        res = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(disk)], capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
        return disk

    yield mount
    if os.path.ismount(disk):
        subprocess.run(["umount", "-l", str(disk)], check=False)


def test_generate_on_a_full_disk_says_so_keeps_its_demos_and_resumes(small_disk, demos_reference):
    """libhdf5 on a full disk printed dozens of tracebacks and crashed (exit 139): one line naming
    the folder and the fix, the finished demo kept whole, and after space is freed the same command
    ends as an uninterrupted run."""
    disk = small_disk("200k")  # one demo (~140 kB) fits, two do not
    res = rsb(*GENERATE, "--out", str(disk / "d"))
    assert res.returncode == 1, res.stderr[-3000:]
    errors = error_lines(res.stderr)
    assert len(errors) == 1 and "no space left on the device of" in errors[0], res.stderr[-3000:]
    assert str(_resume_dir(disk / "d")) in errors[0] and "rerun the same command to continue" in errors[0]
    assert "Traceback" not in res.stderr and "No space left" not in res.stderr
    assert not (disk / "d" / DEMO_FILE).exists() and len(list(_resume_dir(disk / "d").glob("demo*.h5"))) == 1
    small_disk("8m")
    res = rsb(*GENERATE, "--out", str(disk / "d"))
    assert res.returncode == 0, res.stderr[-3000:]
    ref_eps, ref_arrays = _demos(demos_reference)
    eps, arrays = _demos(disk / "d" / DEMO_FILE)
    assert eps == ref_eps and [k for k in arrays if not np.array_equal(arrays[k], ref_arrays[k])] == []
    assert stray_files(disk) == []


def test_eval_on_a_full_disk_names_the_folder_and_leaves_no_half_file(small_disk):
    """"OSError: [Errno 28]" naming nothing, and a 0-byte summary_categories.csv: one line naming the
    folder and the fix, no empty or temp file; the records kept, and the rerun writes the reports."""
    disk = small_disk("64k")
    out = disk / "r"
    res = rsb("eval", "random", *EVAL, "-n", "2", "--max-steps", "3", "--out", str(out))
    assert res.returncode == 1, res.stderr[-3000:]
    errors = error_lines(res.stderr)
    assert len(errors) == 1 and f"cannot write {out}" in errors[0] and "no space left" in errors[0], res.stderr
    assert "Traceback" not in res.stderr and "OSError" not in res.stderr
    assert [p.name for p in out.iterdir() if p.stat().st_size == 0] == [] and stray_files(disk) == []
    small_disk("8m")
    res = rsb("eval", "random", *EVAL, "-n", "2", "--max-steps", "3", "--out", str(out))
    assert res.returncode == 0 and (out / "summary_categories.csv").stat().st_size > 0, res.stderr[-3000:]
    assert lines(out / "episodes.jsonl") == 2


def test_names_that_lose_their_letters_get_a_folder_each(tmp_path, monkeypatch):
    """'模型🤖 é' and '🤖' both became results/policy; "a:b" and "a/b" make one folder name, so the
    second is refused in one line rather than joining the first's folder."""
    from rsb_maniskill.commands.eval_args import EvalError, results_dir

    monkeypatch.chdir(tmp_path)
    folders = {results_dir(None, name) for name in ("模型🤖 é", "🤖", "é", "e\u0301", "policy")}
    assert len(folders) == 4  # NFC: "é" typed two ways is one name; the others one folder each
    assert results_dir(None, "oracle").name == "oracle"  # ASCII names keep their folders
    inside = {results_dir(None, name).resolve().parent for name in ("..", ".", "...")}  # not ./ nor results/
    assert inside == {(tmp_path / "results").resolve()}
    claimed = results_dir(None, "a:b")
    (claimed / "run.json").write_text(json.dumps({"runs": {"a:b": {}}}))
    with pytest.raises(EvalError, match="same folder name"):
        results_dir(None, "a/b")
    assert results_dir(None, "a:b") == claimed


def _case_name_300_chars(tmp: Path) -> tuple[list[str], str]:
    return ["eval", "oracle", *EVAL, "-n", "1", "--name", "n" * 300, "--out", str(tmp / "r")], "give a shorter --name"


def _case_out_300_chars(tmp: Path) -> tuple[list[str], str]:
    return ["eval", "oracle", *EVAL, "-n", "1", "--out", str(tmp / ("o" * 300) / "r")], "File name too long"


def _case_generate_out_300_chars(tmp: Path) -> tuple[list[str], str]:
    return [*GENERATE, "--out", str(tmp / ("o" * 300))], "too long"


def _case_questions_bad_split(tmp: Path) -> tuple[list[str], str]:
    return ["questions", SUITE, "--split", "bogus"], "unknown split 'bogus'"


def _case_name_with_a_newline(tmp: Path) -> tuple[list[str], str]:  # it broke summary.md's table rows
    return ["eval", "oracle", *EVAL, "-n", "1", "--name", "two\nlines", "--out", str(tmp / "r")], \
        "--name 'two\\nlines': holds a control character ('\\n' at position 3)"


def _case_o_a_folder(tmp: Path) -> tuple[list[str], str]:  # -o named the results folder before it named the obs mode
    return ["eval", "oracle", "--suites", SUITE, "-n", "1", "-o", "myresults"], \
        "-o is the obs mode: the results folder is --out myresults (see rsb eval --help)"


def _case_unknown_flag(tmp: Path) -> tuple[list[str], str]:
    return ["eval", "oracle", *EVAL, "--bogus"], \
        "rsb eval: error: unrecognized arguments: --bogus (see rsb eval --help)"


USAGE_CASES = [_case_name_300_chars, _case_out_300_chars, _case_generate_out_300_chars, _case_questions_bad_split,
               _case_name_with_a_newline, _case_o_a_folder, _case_unknown_flag]


@pytest.mark.parametrize("case", USAGE_CASES, ids=[c.__name__[6:] for c in USAGE_CASES])
def test_long_names_and_usage_errors_exit_2_in_one_line(case, tmp_path):
    argv, phrase = case(tmp_path)
    before = tree(tmp_path)
    res = rsb(*argv, timeout=120)
    errors = error_lines(res.stderr)
    assert res.returncode == 2 and len(errors) == 1 and phrase in errors[0], res.stderr[-2000:]
    assert "Traceback" not in res.stderr and "internal" not in res.stderr
    assert tree(tmp_path) == before


def _plugin(tmp: Path, body: str, name: str = "odd") -> dict:
    """An installed plugin distribution (module + entry point) on the path of the commands run with the env."""
    (tmp / f"rsb_{name}_plugin.py").write_text(body)
    info = tmp / f"rsb_{name}_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: rsb-{name}-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[rsb_maniskill.plugins]\n{name} = rsb_{name}_plugin\n")
    return {"PYTHONPATH": os.pathsep.join([str(tmp), str(TESTS), str(REPO)])}


PLUGIN_CASES = [  # (plugin module, phrase of its one line)
    ("import time\ntime.sleep(3600)\n", "its import did not finish within 2 s"),
    ("import sys\nsys.exit(3)\n", "it called sys.exit(3) while importing"),
    ("from rsb_maniskill.policies.registry import register_policy\nregister_policy('oracle', 'os:getcwd')\n",
     "policy name 'oracle' is taken (by rsb_maniskill.policies.reference:oracle)"),
    ("raise KeyboardInterrupt\n", "it raised KeyboardInterrupt while importing (no Ctrl-C was pressed)"),
]


@pytest.mark.parametrize("body, phrase", PLUGIN_CASES,
                         ids=["hangs", "sys.exit", "replaces-oracle", "KeyboardInterrupt"])
def test_a_plugin_that_hangs_exits_or_replaces_a_builtin_is_named_and_skipped(body, phrase, tmp_path):
    """Every command hung, exited 3 without a word, or ran an impostor as `oracle`: `rsb --version`
    needs no plugin; others name the plugin and how to go without it in one line, and run."""
    env = _plugin(tmp_path, body)
    res = rsb("--version", timeout=60, **env)
    assert res.returncode == 0 and res.stdout.startswith("rsb_maniskill ") and res.stderr == "", res.stderr
    check = ("import rsb_maniskill\n"  # reads the suites, which loads the plugins
             "from rsb_maniskill.policies.registry import factory_path\nprint(factory_path('oracle'))")
    res = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=120,
                         env=_env(RSB_PLUGIN_TIMEOUT="2", **env), cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.strip() == "rsb_maniskill.policies.reference:oracle", res.stderr
    notes = [line for line in res.stderr.splitlines() if "plugin" in line]
    assert len(notes) == 1 and "plugin 'odd'" in notes[0] and phrase in notes[0], res.stderr
    assert "RSB_NO_PLUGINS=odd" in notes[0] and "Traceback" not in res.stderr
    res = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=120,
                         env=_env(RSB_NO_PLUGINS="odd", **env), cwd=tmp_path)
    assert res.returncode == 0 and "plugin" not in res.stderr, res.stderr  # the switch it named


def test_a_resume_checks_which_code_made_its_records(tmp_path):
    """The records of `oracle` made by one factory are not extended by another under the same name."""
    from rsb_maniskill.evaluation.records import RECORD_FIELDS, VERSION_FIELD
    from rsb_maniskill.evaluation.store import ManifestError, RecordWriter, check_manifest
    from rsb_maniskill.version import BENCHMARK_VERSION

    settings = {"policy": "oracle", "policy_factory": "rsb_maniskill.policies.reference:oracle"}
    assert check_manifest(tmp_path, "oracle", settings, keys=("policy",)) is None
    with RecordWriter(tmp_path / "episodes.jsonl") as writer:  # one episode of the real oracle
        writer.write({**dict.fromkeys(RECORD_FIELDS, 0), "policy": "oracle", "suite_id": SUITE, "seed": 0,
                      "instruction_mode": "normal", VERSION_FIELD: BENCHMARK_VERSION})
    impostor = {**settings, "policy_factory": "rsb_odd_plugin:Impostor"}
    with pytest.raises(ManifestError, match="made by rsb_maniskill.policies.reference:oracle"):
        check_manifest(tmp_path, "oracle", impostor, keys=("policy",))
    assert check_manifest(tmp_path, "oracle", settings, keys=("policy",)) is None  # the same code resumes


@pytest.fixture
def read_only(tmp_path) -> Path:
    """An empty read-only file system at tmp_path/ro (root ignores file modes, not a read-only mount)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(ro)], capture_output=True,
                         text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
    yield ro
    subprocess.run(["umount", "-l", str(ro)], check=False)


READ_ONLY_CASES = [  # (argv with {ro} for the read-only folder, phrase of the one line)
    ([*GENERATE, "--out", "{ro}/d"], "Read-only file system"),
    (["eval", "oracle", *EVAL, "-n", "1", "--out", "{ro}/r"], "Read-only file system"),
    (["merge", "{pair}", "--out", "{ro}/m.h5"], "Read-only file system"),
    (["audit", SUITE, "-n", "5", "--out", "{ro}/a"], "Read-only file system"),
    (["export", "lerobot", "{pair}", "--out", "{ro}/ds"], "cannot write to --out {ro}/ds: Read-only file system"),
]


@pytest.mark.parametrize("argv, phrase", READ_ONLY_CASES, ids=[c[0][0] for c in READ_ONLY_CASES])
def test_a_read_only_folder_is_one_line_naming_it(argv, phrase, read_only, tmp_path):
    pair = _pair(tmp_path / "a.h5", [0, 1])
    argv = [a.replace("{ro}", str(read_only)).replace("{pair}", str(pair)) for a in argv]
    phrase = phrase.replace("{ro}", str(read_only))
    res = rsb(*argv, timeout=120)
    errors = error_lines(res.stderr)
    assert res.returncode == 2 and len(errors) == 1, res.stderr[-2000:]
    assert phrase in errors[0] and str(read_only) in errors[0] and "Traceback" not in res.stderr


def test_a_merge_killed_before_its_rename_leaves_nothing_after_a_rerun(tmp_path):
    """kill -9 of `rsb merge` leaves its temp pair (named by its pid): the same command removes it."""
    a, b = _pair(tmp_path / "a.h5", [0, 1]), _pair(tmp_path / "b.h5", [2])
    gone = subprocess.Popen(["true"])
    gone.wait()  # a pid no process has now: a killed merge's
    for suffix in (".h5", ".json"):
        (tmp_path / f".m.tmp{gone.pid}.merge{suffix}").write_bytes(b"half")
    res = rsb("merge", str(a), str(b), "--out", str(tmp_path / "m.h5"), timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert stray_files(tmp_path) == [] and len(json.loads((tmp_path / "m.json").read_text())["episodes"]) == 3


def test_a_unicode_name_under_a_non_utf8_locale_is_the_same_name(tmp_path):
    """LC_ALL=POSIX without Python's UTF-8 mode: '模型🤖 é' ended in "surrogates not allowed"; it is
    read as the text typed, and its row and folder are those of a UTF-8 locale."""
    name = "模型🤖 é"
    out = tmp_path / "r"
    res = rsb("eval", "oracle", *EVAL, "-n", "1", "--max-steps", "2", "--name", name, "--out", str(out),
              LC_ALL="POSIX", LANG="POSIX", PYTHONUTF8="0", PYTHONIOENCODING="")
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-2000:]
    from rsb_maniskill.evaluation.store import folder_name

    assert {r["policy"] for r in records(out)} == {name}
    assert (out / f"summary_{folder_name(name)}.png").exists()


LOUD_BACKBONE = '''
from huggingface_hub.utils import tqdm


class Loud:
    """Loads "weights" behind a progress bar, as a transformers model does."""

    def __init__(self):
        for _ in tqdm(range(3), desc="Loading weights"):
            pass

    def answer(self, instruction, images):
        return "A"
'''


def test_backbone_quiet_draws_no_library_progress_bar(tmp_path):
    """`rsb backbone ... -q` drew the "Loading weights" bar of the model it loads."""
    (tmp_path / "rsb_loud_backbone.py").write_text(LOUD_BACKBONE)
    path = os.pathsep.join([str(tmp_path), str(TESTS), str(REPO)])
    runs = {flags: rsb("backbone", "rsb_loud_backbone:Loud", "--suites", SUITE, "-n", "1", *flags, "--out",
                       str(tmp_path / f"r{len(flags)}"), timeout=120, PYTHONPATH=path) for flags in ((), ("-q",))}
    assert all(res.returncode == 0 for res in runs.values()), [r.stderr[-2000:] for r in runs.values()]
    assert "Loading weights" in runs[()].stderr  # the bar the library draws, unless told not to
    assert "Loading weights" not in runs[("-q",)].stderr and "it/s" not in runs[("-q",)].stderr


def test_merge_onto_a_full_disk_is_refused_before_it_writes(small_disk, tmp_path):
    """libhdf5 meeting a full disk may crash the process: the free space is checked first."""
    a, b = _pair(tmp_path / "a.h5", [0, 1]), _pair(tmp_path / "b.h5", [2])
    disk = small_disk("16k")
    res = rsb("merge", str(a), str(b), "--out", str(disk / "m.h5"), timeout=120)
    errors = error_lines(res.stderr)
    assert res.returncode == 2 and len(errors) == 1, res.stderr[-2000:]
    assert f"no space left on the device of {disk}" in errors[0] and "choose another --out" in errors[0]
    assert list(disk.iterdir()) == []


