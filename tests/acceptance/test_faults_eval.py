"""Fault injection, issue 60's second sweep: eval runs.

The run's settings reach every process; every output carries one verdict on its episodes; a policy's
episode is a function of its seed; Ctrl-C stops a run whatever its policy does; errors name what the
user wrote; workers quiet and counted as started.
The shared runners and checks are tests/helpers/fault_runs.py; the first sweep and the reports' rows
are tests/acceptance/test_faults.py (one file each so that the test workers run them side by side)."""
from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

import pytest
from fault_runs import EVAL, SUITE, alive, error_lines, lines, records, rsb, start, wait_until, workers_of

# ------------------------------------------------------------ second sweep: eval runs
# (issue 60) the run's settings reach every process; every output carries one verdict on its
# episodes; a policy's episode is a function of its seed; Ctrl-C stops a run whatever its policy
# does; errors name what the user wrote; workers quiet and counted as started.


def _gsm8k_copy(root: Path, rows: int | None = None) -> Path:
    """A data directory holding a copy of the real GSM8K (its first ``rows`` lines: a cut one)."""
    real = Path(os.environ.get("RSB_DATA_DIR") or "/nonexistent") / "gsm8k"
    if not (real / "test.jsonl").exists():
        pytest.skip("needs the real GSM8K in RSB_DATA_DIR")
    (root / "gsm8k").mkdir(parents=True)
    for name in ("test.jsonl", "train.jsonl"):
        text = (real / name).read_text()
        (root / "gsm8k" / name).write_text("".join(text.splitlines(keepends=True)[:rows]) if rows else text)
    return root


@pytest.mark.data
def test_data_dir_reaches_the_workers_and_every_output_says_what_ran(tmp_path):
    """--data-dir alone (no $RSB_DATA_DIR, no hub cache; the episodes run in a worker process): the
    run uses it and its outputs say the episodes are the version's. On a GSM8K cut to 100 rows the
    run still ends 0, and summary.md, summary.json, results.json and report.html say they are not
    (the Markdown on its first line), and so does eval's last line."""
    alone = dict(RSB_DATA_DIR="", HF_HOME=str(tmp_path / "hf"), HF_HUB_OFFLINE="1")
    run = ["eval", "random", "--suites", "RSB-HardMath-4", "-o", "state", "-q", "-n", "1", "--max-steps", "5"]
    verdicts = {}
    for name, rows in (("full", None), ("cut", 100)):
        out = tmp_path / name
        res = rsb(*run, "--data-dir", str(_gsm8k_copy(tmp_path / f"data-{name}", rows)), "--out", str(out), **alone)
        assert res.returncode == 0, res.stderr[-2000:]
        verdicts[name] = {json.loads((out / "results.json").read_text())["rows"][0]["episodes"],
                          json.loads((out / "summary.json").read_text())["episodes"]}
        said = [line for line in res.stderr.splitlines() if line.strip()] or [""]  # -q: a good run says nothing
        differ = "episodes differ from RSB-MS"
        assert (differ in said[-1]) == (rows is not None), res.stderr[-2000:]
        assert ((out / "summary.md").read_text().splitlines()[0].startswith(f"**{differ}")) == (rows is not None)
        assert (differ in (out / "report.html").read_text()) == (rows is not None)
    assert verdicts == {"full": {"pinned"}, "cut": {"differ"}}


def test_a_policys_episode_is_a_function_of_its_seed(tmp_path):
    """One env in one process, then two envs in each of two workers (other company, other order):
    the same records per seed, the policy's draws included (its text names a digest of each chunk)."""
    runs = []
    for name, flags in (("k1", []), ("k2p2", ["--num-envs", "2", "--num-procs", "2"])):
        out = tmp_path / name
        res = rsb("eval", "bad_policies:draws", *EVAL, "-n", "3", "--max-steps", "10", "--name", "draws", *flags,
                  "--out", str(out))
        assert res.returncode == 0, res.stderr[-2000:]
        runs.append(records(out))
    assert len({r["text"] for r in runs[0]}) == 3  # each episode drew its own numbers
    assert runs[0] == runs[1]


@pytest.mark.parametrize("reseed", [True, False], ids=["reseeds", "draws-across-episodes"])
def test_the_seed_check_catches_a_policy_that_draws_across_episodes(reseed):
    """The check above, in this process on the fake env: a policy with one generator for all its
    episodes draws other numbers for a seed under K = 2 than under K = 1; one that reseeds does not."""
    from rsb_maniskill.evaluation.runner import EpisodeSettings, batched_loop, episode_loop

    from bad_policies import Draws
    from fake_envs import SEEDS, FakeBatchedEnv, FakeRSBEnv

    seeds = SEEDS[:3]
    settings = EpisodeSettings(suite_id=SUITE, seeds=seeds, label="draws", max_steps=10)
    logs = []
    for run in (lambda: episode_loop(FakeRSBEnv(), Draws(reseed, talk=False), settings, seeds, [].append),
                lambda: batched_loop(FakeBatchedEnv(2), [Draws(reseed, talk=False), Draws(reseed, talk=False)],
                                     settings, seeds, [].append)):
        Draws.log.clear()
        run()
        logs.append(dict(Draws.log))
    assert sorted(logs[0]) == seeds
    assert (logs[0] == logs[1]) == reseed


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("signals", [[signal.SIGINT], [signal.SIGTERM], [signal.SIGINT, signal.SIGINT]],
                         ids=["ctrl-c", "sigterm", "ctrl-c-twice"])
def test_a_run_whose_policy_ignores_signals_stops_at_once(signals, tmp_path):
    """act blocks with SIGINT / SIGTERM ignored and no --policy-timeout (it would wait forever):
    the signal stops the run all the same (the worker killed after a short grace, at once on a second
    Ctrl-C), exit 130, the finished episode kept, the worker gone."""
    out, marker = tmp_path / "r", tmp_path / "blocked"
    proc = start("eval", "bad_policies:deaf_hangs", "-a", "after=3", *EVAL, "-n", "2", "--max-steps", "3",
                 "--policy-timeout", "0", "--out", str(out), RSB_TEST_BLOCKED_MARKER=str(marker))
    assert wait_until(marker.exists, proc), proc.communicate()[1][-2000:]
    workers = workers_of(proc.pid)
    t0 = time.monotonic()
    for sig in signals:
        proc.send_signal(sig)
        time.sleep(0.5)
    out_text, err_text = proc.communicate(timeout=240)
    rc, log = proc.returncode, out_text + err_text
    assert time.monotonic() - t0 < 60  # stopped, not waiting on the policy (5 s grace; 0: no policy limit)
    assert rc == 130 and "Rerun the same command to resume" in log and "Traceback" not in log, log[-2000:]
    assert lines(out / "episodes.jsonl") == 1
    assert workers and not [w for w in workers if alive(w)]


def test_an_act_only_policy_on_two_envs_is_blamed_for_its_act_on_its_seed(tmp_path):
    """A policy with act alone, run two envs a process, raises in the second env's episode: the error
    names act (not act_batch, which the user never wrote) and that episode's seed (not a range)."""
    from rsb_maniskill.evaluation.protocol import eval_seeds

    seed = list(eval_seeds(SUITE, 2))[1]
    res = rsb("eval", "bad_policies:act_fails", "-a", f"on={seed}", *EVAL, "-n", "2", "--max-steps", "3",
              "--num-envs", "2", "--num-procs", "1", "--out", str(tmp_path / "r"))
    errors = error_lines(res.stderr)
    assert res.returncode == 1 and len(errors) == 1, res.stderr[-2000:]
    assert f"seed {seed} " in errors[0] and "act raised RuntimeError" in errors[0], errors[0]
    assert "act_batch" not in errors[0] and "seeds" not in errors[0], errors[0]


def test_workers_that_do_not_exit_cost_one_wait_not_one_each():
    """8 workers whose process lingers after its work (a policy's thread): the run ends with every
    result, the workers killed after one shared wait (10 s), not 10 s each one after the other (80 s)."""
    from rsb_maniskill.parallel.pool import EXIT_WAIT_S, ProcessPool

    from bad_policies import lingers

    seen: list = []
    t0 = time.monotonic()
    outcome = ProcessPool().run(lingers, list(range(8)), seen.append)
    assert [t.result for t in outcome.tasks] == list(range(8)) and sorted(seen) == list(range(8))
    assert time.monotonic() - t0 < 8 * EXIT_WAIT_S  # the waits one after the other would take this alone


def test_a_dataset_build_says_how_many_workers_start(capsys):
    """`rsb dataset build --num-procs 99` over 2 shards: 2 workers start, one a shard, and it says so
    (the plan's line before it named the 99 asked for)."""
    from rsb_maniskill.export.build import _run
    from rsb_maniskill.export.shards import SuiteShard
    from rsb_maniskill.parallel.pool import RunOutcome

    class Recorder:
        def run(self, target, tasks, on_message):
            self.tasks = tasks
            return RunOutcome([])

    rec = Recorder()
    _run([(Path("/w"), {"env_id": SUITE}, k, SuiteShard(SUITE, k, k + 1)) for k in range(2)], 99, rec,
         progress=False)
    assert len(rec.tasks) == 2 and "workers: 2 started, one a shard (2 shards for --num-procs 99)" in \
        capsys.readouterr().err


def test_workers_are_quiet_plain_and_counted_as_started(tmp_path):
    """--num-procs 99 for 2 episodes: the line says the 2 workers that start, and no worker prints
    ManiSkill's render-device warning (nothing renders) nor colour codes."""
    loud = [a for a in EVAL if a != "-q"]  # -q drops the lines saying what the run chose
    res = rsb("eval", "random", *loud, "-n", "2", "--max-steps", "2", "--num-procs", "99", "--out",
              str(tmp_path / "r"), NO_COLOR="1")
    assert res.returncode == 0, res.stderr[-2000:]
    assert "workers: 2 processes" in res.stderr and "99 processes" not in res.stderr, res.stderr[-2000:]
    assert "Rendering might be disabled" not in res.stderr and "\x1b[" not in res.stderr, res.stderr[-2000:]




# ------------------------------------------------------------ a policy's own KeyboardInterrupt, a killed worker


@pytest.mark.parametrize("where, call", [("factory", "building it"), ("act", "act")])
def test_a_policys_own_keyboard_interrupt_is_one_line_naming_it_and_the_call(where, call, tmp_path):
    """KeyboardInterrupt raised by the policy itself (no Ctrl-C sent), in its factory or in act: one
    error line naming the policy and the call (was "worker 0: KeyboardInterrupt() ..."), no traceback."""
    res = rsb("eval", "bad_policies:exits", "-a", "how=KeyboardInterrupt", "-a", f"where={where}", *EVAL, "-n", "1",
              "--max-steps", "3", "--out", str(tmp_path / "r"))
    errors = error_lines(res.stderr)
    assert res.returncode == 1 and len(errors) == 1 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert errors[0].startswith(f"rsb eval: error: policy 'bad_policies:exits' on {SUITE}"), errors[0]
    assert f": {call} raised KeyboardInterrupt with no Ctrl-C sent" in errors[0] and "worker" not in errors[0]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_worker_killed_by_sigkill_says_so_what_was_lost_and_that_a_rerun_resumes(tmp_path):
    """kill -9 of a worker (as the out-of-memory killer does) while its policy waits in act: one line
    naming the signal and its likely cause, the suite and seeds not recorded, and that a rerun resumes
    (was "exited with code -9")."""
    from rsb_maniskill.evaluation.protocol import eval_seeds

    out = tmp_path / "r"
    proc = start("eval", "bad_policies:hangs", "-a", "after=3", *EVAL, "-n", "3", "--max-steps", "3",
                 "--num-procs", "1", "--policy-timeout", "0", "--out", str(out))
    assert wait_until(lambda: lines(out / "episodes.jsonl") >= 1, proc), proc.communicate()[1][-2000:]
    workers = workers_of(proc.pid)
    assert len(workers) == 1
    os.kill(workers[0], signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    lost = ", ".join(map(str, eval_seeds(SUITE, 3)[1:]))
    assert proc.returncode == 1 and error_lines(err) == [
        "rsb eval: error: evaluation worker 0 was killed by SIGKILL (likely out of memory, or killed by the user), "
        f"running {SUITE} seeds {lost} (normal instruction): those episodes were not recorded; rerun the same "
        "command to resume: finished episodes are kept"], err[-2000:]
