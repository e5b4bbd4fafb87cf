"""One default limit on a policy call, wherever the policy runs: `rsb eval`'s workers and a policy server
(`rsb serve`, and the shared one `rsb eval` starts, which is given the run's value) take policies.errors'."""
from __future__ import annotations

from rsb_maniskill.cli import build_parser
from rsb_maniskill.policies.errors import POLICY_TIMEOUT_S


def test_eval_and_serve_default_to_the_same_policy_timeout():
    eval_args = build_parser().parse_args(["eval", "oracle"])
    serve_args = build_parser().parse_args(["serve", "random"])
    assert eval_args.policy_timeout == serve_args.policy_timeout == POLICY_TIMEOUT_S
