"""A remote run is the same run whatever host and port its server answers on: how the model is reached
(host, port, token, timeouts) is not part of a row's settings, nor written to run.json; a run.json of
an older version, which kept them, still resumes."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from rsb_maniskill.commands.eval_args import MANIFEST_KEYS, TRANSPORT_ARGS, run_settings
from rsb_maniskill.evaluation.store import (
    MANIFEST_FILE,
    RECORDS_FILE,
    SETTINGS_FIELD,
    ManifestError,
    check_manifest,
    settings_id,
)
from rsb_maniskill.version import BENCHMARK_VERSION

from fake_records import records


def settings(port: int, preset: str = "openpi-aloha", policy: str = "remote") -> dict:
    """What rsb eval gathers for a row (``eval._run_eval``), before run_settings."""
    return dict(policy=policy, policy_kwargs={"host": "gpu-box", "port": port, "token": "s3cret", "preset": preset,
                                              "connect_timeout": 5},
                obs_mode="rgb", control_mode=None, max_steps=300, env_kwargs={}, benchmark_version=BENCHMARK_VERSION,
                checkpoint=None, policy_factory="rsb_maniskill.policies.remote:remote_policy")


def record(out: Path, stamp: str) -> None:
    """One finished episode of 'pi05', carrying the settings id it ran with."""
    row = {**records("pi05", "RSB-Math-4", 1, 0, 0)[0], "question_id": 0, "instruction": "x", "target_block": 0,
           "correct_letter": "A", "first_grasped": 0, "steps": 5, "benchmark_version": BENCHMARK_VERSION,
           SETTINGS_FIELD: stamp}
    with open(out / RECORDS_FILE, "a") as f:
        f.write(json.dumps(row) + "\n")


def resume(out: Path, raw: dict) -> str | None:
    return check_manifest(out, "pi05", run_settings(raw), keys=MANIFEST_KEYS, read_row=run_settings)


def test_the_server_on_another_port_is_the_same_run(tmp_path):
    first = run_settings(settings(8000))
    assert resume(tmp_path, settings(8000)) is None
    written = (tmp_path / MANIFEST_FILE).read_text()
    assert "s3cret" not in written and "gpu-box" not in written and "8000" not in written  # nor the token
    assert json.loads(written)["runs"]["pi05"]["policy_kwargs"] == {"preset": "openpi-aloha"}
    record(tmp_path, settings_id(first, MANIFEST_KEYS))
    assert resume(tmp_path, settings(9001)) is None  # the server came back elsewhere: it resumes
    with pytest.raises(ManifestError, match="other settings"):  # what the model is still counts
        resume(tmp_path, settings(9001, preset="openpi-droid"))


def test_a_run_json_that_kept_the_port_still_resumes(tmp_path):
    """An older version wrote host, port and token into run.json and digested them into the records'
    settings id: its run resumes on another port, and its row is kept as written."""
    old = settings(8000)
    row = {**old, "rsb_version": "0.9", "code_commit": None}
    (tmp_path / MANIFEST_FILE).write_text(json.dumps({"runs": {"pi05": row}}))
    record(tmp_path, settings_id(old, MANIFEST_KEYS))
    assert resume(tmp_path, settings(9001)) is None
    assert json.loads((tmp_path / MANIFEST_FILE).read_text())["runs"]["pi05"] == row
    with pytest.raises(ManifestError, match="other settings"):
        resume(tmp_path, settings(9001, preset="openpi-droid"))


def test_only_the_remote_policys_transport_is_left_out():
    mine = settings(8000, policy="my_policies:make")  # a factory's own "port" may be what the policy is
    assert run_settings(mine) == mine
    kept = run_settings(settings(8000))["policy_kwargs"]
    assert kept == {"preset": "openpi-aloha"} and not set(kept) & set(TRANSPORT_ARGS)
    backbone = run_settings({"backbone": "remote", "backbone_kwargs": {"port": 1, "name": "qwen"}})
    assert backbone["backbone_kwargs"] == {"name": "qwen"}


class Still:
    """A served policy: every arm and gripper held where it is (zeros of the 14 joint targets' deltas)."""

    def reset(self, instruction, obs) -> None:
        pass

    def act(self, obs):
        import numpy as np

        return np.zeros((1, 14), dtype=np.float32)

    def fork(self) -> "Still":
        return self


def test_rsb_eval_remote_resumes_when_its_server_comes_back_on_another_port(tmp_path, capsys):
    """The whole path: a run of one episode against a server on one port, then the same command with
    -n 2 against the server restarted on another port adds the second episode to the same row."""
    from rsb_maniskill.cli import main
    from rsb_maniskill.policies.remote.server import PolicyServer

    out = tmp_path / "r"
    common = ["--suites", "RSB-Math-4", "-o", "state", "--max-steps", "3", "-q", "--name", "pi05", "--out", str(out)]
    for n in (1, 2):
        with PolicyServer(Still(), host="127.0.0.1", port=0) as server:  # a free port: another one each time
            capsys.readouterr()
            assert main(["eval", "remote", "-a", f"port={server.port}", "-a", "token=s3cret", "-a",
                         "connect_timeout=30", "-n", str(n), *common]) == 0, capsys.readouterr().err
    lines = (out / RECORDS_FILE).read_text().splitlines()
    assert len(lines) == 2 and len({json.loads(line)[SETTINGS_FIELD] for line in lines}) == 1
    assert json.loads((out / MANIFEST_FILE).read_text())["runs"]["pi05"]["policy_kwargs"] == {}
    assert "s3cret" not in (out / MANIFEST_FILE).read_text() + (out / "report.html").read_text()
