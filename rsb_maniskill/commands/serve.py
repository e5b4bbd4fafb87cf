"""`rsb serve`: one policy for every client, over openpi's websocket protocol, batching their envs.

    rsb serve my_policies:make_policy -a checkpoint=ckpt/last --port 8000
    rsb serve my_policies:make_policy --port 8000 --max-batch 64 --max-wait-ms 25
    rsb eval remote -a host=gpu-box -a port=8000 --num-procs 16 --num-envs 4    # on the eval machine

The policy is built once; the requests of every connection are gathered for at most
``--max-wait-ms`` or ``--max-batch`` rows (envs) and answered by one ``act_batch`` over all their
rows (``policies/remote/batching.py``; a single-env policy: one row at a time, each env its own copy,
said at start). A policy call longer than ``--policy-timeout`` fails its rows; Ctrl-C stops the server
within a few seconds whatever the policy does. The server is ``policies/remote/server.py``;
``rsb eval --policy-process shared`` starts one itself.
"""
from __future__ import annotations

import argparse
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    from rsb_maniskill.policies.remote.server import add_serve_args

    p = subparsers.add_parser(
        "serve", help="serve a policy over openpi's websocket protocol, every client's envs in one batched call",
        description="Builds POLICY once and serves it on ws://HOST:PORT (openpi's protocol: openpi clients, "
                    "`rsb eval remote` and the vla-eval adapter talk to it). Requests of all connections are "
                    "gathered for at most --max-wait-ms or --max-batch rows and answered by one act_batch; "
                    "the batch sizes formed are printed when it stops (Ctrl-C).")
    add_serve_args(p)
    p.set_defaults(func=run_serve)


def run_serve(args: argparse.Namespace) -> int:
    """Exit status: 0 when stopped (Ctrl-C, SIGTERM), 2 for a wrong argument or policy, 1 when the
    server cannot listen (a port taken). Library log lines only with ``rsb --debug``."""
    from rsb_maniskill.policies.remote.server import ServeError, run_server

    try:
        return run_server(args)
    except (ValueError, TypeError, ImportError, AttributeError) as err:  # a spec or argument that is wrong
        print(f"rsb serve: error: {err}", file=sys.stderr)
        return 2
    except ServeError as err:
        print(f"rsb serve: error: {err}", file=sys.stderr)
        return 1
