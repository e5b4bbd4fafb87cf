"""One model for every worker, end to end: `rsb eval --policy-process shared` against `worker`, with the
simulator and a model that computes.

    python benchmarks/policy_server.py [--procs 2] [--envs 1 4] [-n 8] [--max-steps 40]
                                       [--max-wait-ms 25 0] [--repeats 3] [--hidden 2048] [--layers 4]
                                       [--horizon 4] [--threads 0] [--device cpu]

The model: a torch MLP (state observation -> ``--layers`` hidden layers of ``--hidden`` -> a chunk of
``--horizon`` actions), both policy forms and the served form's ``reset_envs``, one forward pass over
the rows of each call, declared ``heavy`` (this module's ``make_mlp``, importable by the eval's
processes), with torch's threads as ``rsb eval`` gives each process (``--threads 0``): a worker its
share of the cores (cores // P), the shared server the same share. Each (P workers, K envs a worker)
runs the same seeds with ``--policy-process worker`` (a copy a worker) and ``shared`` (one server
process, every worker's rows batched) at each ``--max-wait-ms`` T (25: the default; 0: no wait for
other workers' rows), ``--repeats`` times, interleaved, the median kept. Timed: the whole command
(start-up included, what a user waits for) and the steady env-steps/s of its own throughput line;
the shared run's batch sizes; and, in this process, one forward pass over 1, 2, 4, 8 and 16 rows
at the server's threads for the first ``--procs`` (how the model's cost grows with its rows).
``--device cuda`` puts the model on the GPU (where the batch should pay). Recorded to
``benchmarks/results/policy_server.json`` (``--name`` another file).
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

HERE = Path(__file__).resolve().parent
SUITE = "RSB-Direct-4"  # no question data needed
OBS_DIM, ACTION_DIM = 117, 14
THROUGHPUT = re.compile(r"throughput: start-up ([\d.,]+) s, then ([\d.,]+) env-steps/s \(([\d,]+) env-steps")
BATCHES = re.compile(r"batches formed: (\d+) policy calls, ([\d.]+) rows a call")


class MLPPolicy:
    """A model that computes: ``layers`` x ``hidden`` MLP from the state to a chunk; stateless between
    calls, so its chunks are the same in any grouping of rows."""

    name = "mlp"

    def __init__(self, hidden: int = 2048, layers: int = 4, horizon: int = 4, device: str = "cpu",
                 threads: int | None = 0) -> None:
        import torch

        if threads:
            torch.set_num_threads(int(threads))
        torch.manual_seed(0)
        dims = [OBS_DIM] + [hidden] * layers
        mods: list[Any] = []
        for a, b in zip(dims, dims[1:]):
            mods += [torch.nn.Linear(a, b), torch.nn.ReLU()]
        self.net = torch.nn.Sequential(*mods, torch.nn.Linear(dims[-1], horizon * ACTION_DIM)).to(device).eval()
        self.horizon, self.device = horizon, device

    def reset(self, instruction: str, obs: Any, seed: int | None = None) -> None:
        pass

    def act(self, obs: Any) -> np.ndarray:
        return self.act_batch(np.asarray(obs)[None], [0])[0]

    def reset_batch(self, instructions: Any, obs: Any, seeds: Any = None) -> None:
        pass

    def reset_envs(self, instructions: Any, obs: Any, envs: Any, seeds: Any = None) -> None:
        pass

    def act_batch(self, obs: Any, envs: Any) -> np.ndarray:
        import torch

        with torch.no_grad():
            x = torch.as_tensor(np.asarray(obs, dtype=np.float32), device=self.device)
            out = torch.tanh(self.net(x)).reshape(len(envs), self.horizon, ACTION_DIM)
        return out.cpu().numpy()


def make_mlp(hidden: int = 2048, layers: int = 4, horizon: int = 4, device: str = "cpu",
             threads: int | None = 0) -> MLPPolicy:
    return MLPPolicy(hidden, layers, horizon, device, threads)


make_mlp.heavy = True  # a model: what `rsb eval --policy-process auto` weighs sharing for


def forward_threads(args: argparse.Namespace) -> int:
    """The torch threads of the model in the shared server of the first ``--procs`` workers."""
    from rsb_maniskill.parallel.threads import cpu_share

    return args.threads or cpu_share(args.procs[0])


def forward_ms(args: argparse.Namespace, rows: list[int], repeats: int = 20) -> dict[int, float]:
    """One forward pass over ``rows`` rows, ms (median of ``repeats``), in this process."""
    import torch

    policy = make_mlp(args.hidden, args.layers, args.horizon, args.device, forward_threads(args))
    out = {}
    for n in rows:
        obs = np.random.default_rng(0).standard_normal((n, OBS_DIM)).astype(np.float32)
        policy.act_batch(obs, list(range(n)))  # warm
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            policy.act_batch(obs, list(range(n)))
            if args.device != "cpu":
                torch.cuda.synchronize()
            times.append(1000 * (time.perf_counter() - t0))
        out[n] = float(np.median(times))
    return out


def eval_run(args: argparse.Namespace, mode: str, procs: int, envs: int, wait: float | None = None) -> dict[str, Any]:
    """One `rsb eval` of the MLP: wall time, the throughput line's figures, the batch sizes (shared)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", "policy_server:make_mlp",
               "-a", f"hidden={args.hidden}", "-a", f"layers={args.layers}", "-a", f"horizon={args.horizon}",
               "-a", f"device={args.device}", "-a", f"threads={args.threads}", "--suites", SUITE, "-o", "state",
               "-n", str(args.num_episodes),
               "--max-steps", str(args.max_steps), "--num-procs", str(procs), "--num-envs", str(envs),
               "--policy-process", mode, "--out", tmp] + ([] if wait is None else ["--max-wait-ms", f"{wait:g}"])
        t0 = time.perf_counter()
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=3600)
        wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"rsb eval failed ({mode}, P={procs}, K={envs}):\n{done.stderr[-3000:]}")
    found = THROUGHPUT.search(done.stdout + done.stderr)
    batches = BATCHES.search(done.stderr)
    return {"wall_s": round(wall, 2),
            "start_up_s": float(found.group(1).replace(",", "")) if found else None,
            "env_steps_per_s": float(found.group(2).replace(",", "")) if found else None,
            "env_steps": int(found.group(3).replace(",", "")) if found else None,
            "policy_calls": int(batches.group(1)) if batches else None,
            "rows_a_call": float(batches.group(2)) if batches else None}


def _median(tries: list[dict[str, Any]]) -> dict[str, Any]:
    """Each figure's median over the tries (the tries kept beside it)."""
    return {k: (float(np.median([t[k] for t in tries])) if all(t[k] is not None for t in tries) else None)
            for k in tries[0]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--procs", type=int, nargs="+", default=[2], help="worker processes P")
    p.add_argument("--envs", type=int, nargs="+", default=[1, 4], help="envs a worker K")
    p.add_argument("-n", "--num-episodes", type=int, default=8)
    p.add_argument("--max-steps", type=int, default=40)
    p.add_argument("--hidden", type=int, default=2048)
    p.add_argument("--layers", type=int, default=4)
    p.add_argument("--horizon", type=int, default=4, help="actions a chunk (a policy call every HORIZON steps)")
    p.add_argument("--device", default="cpu", help="where the model computes (cuda: on the GPU)")
    p.add_argument("--threads", type=int, default=0,
                   help="torch threads of the model in each process that holds it (0: the process's share of "
                        "the cores, as rsb eval sets it)")
    p.add_argument("--max-wait-ms", type=float, nargs="+", default=[25.0, 0.0],
                   help="the shared runs' --max-wait-ms T, one shared run each (25: rsb eval's default)")
    p.add_argument("--repeats", type=int, default=3, help="runs of each mode, interleaved; the median is kept")
    p.add_argument("--name", default="policy_server", help="the recorded file's name (benchmarks/results/NAME.json)")
    args = p.parse_args()
    model = make_mlp(args.hidden, args.layers, args.horizon, threads=args.threads)
    params = sum(x.numel() for x in model.net.parameters())
    forward = forward_ms(args, [1, 2, 4, 8, 16])
    print(f"model: MLP {args.layers} x {args.hidden} ({params / 1e6:.1f} M parameters) on {args.device}, "
          f"{f'{args.threads} torch thread(s)' if args.threads else 'torch: each process its share of the cores'}, "
          f"chunks of {args.horizon}; {SUITE}, state obs, "
          f"{args.num_episodes} episodes of {args.max_steps} steps; median of {args.repeats} runs each; "
          f"{os.cpu_count()} CPUs, 1-min load {os.getloadavg()[0]:.1f}")
    print(f"forward pass ({forward_threads(args)} torch thread(s)), ms: "
          + ", ".join(f"{n} rows {ms:.2f}" for n, ms in forward.items()))
    columns = ["P x K", "policy process", "wall s", "/ worker", "env-steps/s", "rows a call"]
    print("| " + " | ".join(columns) + " |")
    print("|---|---|" + "---:|" * (len(columns) - 2))
    modes = {"worker": ("worker", None), **{f"shared T={t:g}": ("shared", t) for t in args.max_wait_ms}}
    rows, runs = [], []
    for procs in args.procs:
        for envs in args.envs:
            tries: dict[str, list] = {name: [] for name in modes}
            for _ in range(args.repeats):  # interleaved: load from other work falls on every mode alike
                for name, (mode, wait) in modes.items():
                    tries[name].append(eval_run(args, mode, procs, envs, wait))
            got = {name: _median(t) for name, t in tries.items()}
            runs.append({"procs": procs, "envs": envs, "worker": got["worker"],
                         "shared": {f"{t:g}": got[f"shared T={t:g}"] for t in args.max_wait_ms}, "tries": tries})
            for name, fig in got.items():
                label = "worker (a copy each)" if name == "worker" else f"shared, --max-wait-ms {modes[name][1]:g}"
                row = [f"{procs} x {envs}", label, f"{fig['wall_s']:.1f}",
                       f"{fig['wall_s'] / got['worker']['wall_s']:.2f}x", f"{fig['env_steps_per_s'] or 0:,.0f}",
                       "" if fig["rows_a_call"] is None else f"{fig['rows_a_call']:.1f} of {procs * envs}"]
                rows.append(row)
                print("| " + " | ".join(row) + " |", flush=True)
    write(args.name, {"model": {"kind": "mlp", "hidden": args.hidden, "layers": args.layers,
                                "horizon": args.horizon, "device": args.device, "threads": args.threads,
                                "parameters": params},
                      "suite": SUITE, "episodes": args.num_episodes, "max_steps": args.max_steps,
                      "max_wait_ms": args.max_wait_ms, "repeats": args.repeats,
                      "forward_threads": forward_threads(args),
                      "forward_ms": {str(n): round(ms, 3) for n, ms in forward.items()}, "runs": runs,
                      "table": table(columns, rows, "llrrrr")},
          notes="wall: the whole rsb eval command, start-up included; env-steps/s: its own throughput line "
                "(steady time); each figure the median of the interleaved tries (kept in runs[].tries)")


if __name__ == "__main__":
    main()
