"""One model for P workers x K envs: today's server (one request at a time) against the batching server.

    python benchmarks/policy_server.py [--procs 1 2 4 8] [--envs 4] [--waves 3] [--fixed-ms 50] [--row-ms 1]

A stand-in model whose forward pass costs ``--fixed-ms`` plus ``--row-ms`` a row (``time.sleep``, then a
small torch MLP over the rows: the actions depend on the observations) and holds ``--model-mib`` of
weights is built once in a server process of its own (as ``rsb eval --policy-process shared`` starts
one) and served there on 127.0.0.1 by ``PolicyServer(..., batching=False)`` (the server before: one
lock around each request) and by the batching server at each ``--max-wait-ms`` T. P worker
processes of K envs each (state observations: RSB's 117 floats a row; torch loaded, as an ``rsb eval``
worker has it for ManiSkill) drive each server as ``rsb eval`` workers do (``RemotePolicy``, one
batched request per chunk, episode starts marked); then each builds its own copy of the model
(``--policy-process worker``). The simulator is left out (zero-cost steps): what is measured is the
policy path; ``rsb eval`` adds its steps on top.

Prints, per P: episodes/s through today's server and the batching server at each T with the ratio,
the batch sizes the batching server formed (rows a call: calls, warm-up calls left out), and peak
memory (the sum of the processes' peak RSS) of ``shared`` (the server process + P clients) against
``worker`` (P processes, each with its copy). Each P is measured in one run, its rows back to back,
so load from other processes falls on each of them.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import threading
import time
from typing import Any

import numpy as np

OBS_DIM = 117  # RSB's state observation
ACTION_DIM = 14
HORIZON = 4  # actions a chunk
STEPS = 8  # steps an episode: two chunks


class StandIn:
    """The stand-in model: both forms and the served form's ``reset_envs``; a forward pass costs
    ``fixed_ms`` + ``row_ms`` a row (asleep, as a GPU call leaves the CPU) plus a small MLP."""

    def __init__(self, model_mib: int = 256, fixed_ms: float = 50.0, row_ms: float = 1.0) -> None:
        import torch

        torch.manual_seed(0)
        torch.set_num_threads(1)
        self.net = torch.nn.Sequential(torch.nn.Linear(OBS_DIM, 64), torch.nn.ReLU(),
                                       torch.nn.Linear(64, HORIZON * ACTION_DIM))
        # the model's memory (a VLA's weights): touched once, so that it is resident, not only reserved
        self.weights = torch.ones(model_mib * 2**20 // 4, dtype=torch.float32)
        self.fixed_s, self.row_s = fixed_ms / 1000.0, row_ms / 1000.0

    def reset(self, instruction: str, obs: Any) -> None:
        pass

    def act(self, obs: Any) -> np.ndarray:
        return self.act_batch(np.asarray(obs)[None], [0])[0]

    def reset_batch(self, instructions: Any, obs: Any) -> None:
        pass

    def reset_envs(self, instructions: Any, obs: Any, envs: Any) -> None:
        pass

    def act_batch(self, obs: Any, envs: Any) -> np.ndarray:
        import torch

        time.sleep(self.fixed_s + self.row_s * len(envs))
        with torch.no_grad():
            out = self.net(torch.as_tensor(np.array(obs, dtype=np.float32)))
        return out.reshape(len(envs), HORIZON, ACTION_DIM).numpy()


def _episodes(policy: Any, envs: int, waves: int, seed: int) -> int:
    """What an ``rsb eval`` worker does with its policy, the steps left out: per wave, reset every env,
    then one call per chunk for the envs (all in step here)."""
    rng = np.random.default_rng(seed)
    for _ in range(waves):
        obs = rng.standard_normal((envs, OBS_DIM)).astype(np.float32)
        policy.reset_batch(["put the answer in the zone"] * envs, obs)
        for _ in range(STEPS // HORIZON):
            chunks = policy.act_batch(obs, list(range(envs)))
            assert len(chunks) == envs
            obs = obs + 0.01
    return waves * envs


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _worker(index: int, ports: dict[str, int], args: argparse.Namespace, barrier: Any, out: Any) -> None:
    import torch  # noqa: F401  (an rsb eval worker has torch loaded: ManiSkill's envs)

    from rsb_maniskill.policies.remote.client import RemotePolicy

    clients = {name: RemotePolicy("127.0.0.1", port, mark_episode_start=True, connect_timeout=60,
                                  request_timeout=600) for name, port in ports.items()}
    for client in clients.values():  # warm: connected, the first call's one-time costs paid
        _episodes(client, args.envs, 1, index)
    for name in ports:  # measured: the time between the two waits of the main process
        barrier.wait()
        _episodes(clients[name], args.envs, args.waves, index)
        barrier.wait()
    rss_shared = _peak_rss_mb()
    for client in clients.values():
        client.close()
    own = StandIn(args.model_mib, args.fixed_ms, args.row_ms)  # --policy-process worker: its own copy
    _episodes(own, args.envs, 1, index)
    barrier.wait()
    _episodes(own, args.envs, args.waves, index)
    barrier.wait()
    out.put((index, rss_shared, _peak_rss_mb()))


def _server(args: argparse.Namespace, ports: Any, stop: Any, out: Any) -> None:
    """The shared policy process (as ``rsb eval --policy-process shared`` starts one): the model built
    once, served by today's server and by the batching server at each T; then its batch sizes and peak RSS."""
    from rsb_maniskill.policies.remote.server import PolicyServer

    model = StandIn(args.model_mib, args.fixed_ms, args.row_ms)
    servers = {"serial": PolicyServer(model, "127.0.0.1", 0, batching=False).start()}
    for t in args.max_wait_ms:
        servers[f"T={t:g}"] = PolicyServer(model, "127.0.0.1", 0, max_batch=args.max_batch, max_wait_ms=t).start()
    ports.put({k: s.port for k, s in servers.items()})
    if stop.get() == "clear":  # every worker warmed up on every server: count the measured batches only
        for s in servers.values():
            if s.batcher is not None:
                s.batcher.sizes.clear()
    stop.get()
    for s in servers.values():
        s.shutdown()
    out.put(({k: s.batcher.summary() for k, s in servers.items() if s.batcher is not None}, _peak_rss_mb()))


def run(procs: int, args: argparse.Namespace) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    ports, stop, served = ctx.Queue(), ctx.Queue(), ctx.Queue()
    server = ctx.Process(target=_server, args=(args, ports, stop, served))
    server.start()
    names = ports.get(timeout=180)
    barrier, out = ctx.Barrier(procs + 1), ctx.Queue()
    workers = [ctx.Process(target=_worker, args=(i, names, args, barrier, out)) for i in range(procs)]
    for w in workers:
        w.start()
    seconds = {}
    try:
        for name in (*names, "worker"):
            barrier.wait(timeout=180)
            if name == "serial":
                stop.put("clear")
            t0 = time.perf_counter()
            barrier.wait(timeout=180)
            seconds[name] = time.perf_counter() - t0
        rss = [out.get(timeout=120) for _ in workers]
    finally:
        stop.put("stop")
        for w in workers:
            w.join(timeout=30)
    summary, server_rss = served.get(timeout=60)
    server.join(timeout=30)
    episodes = procs * args.envs * args.waves
    return {"procs": procs, "episodes": episodes, "eps": {k: episodes / v for k, v in seconds.items()},
            "summary": summary, "rss_shared_mb": server_rss + sum(r[1] for r in rss),
            "rss_worker_mb": sum(r[2] for r in rss)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--procs", type=int, nargs="+", default=[1, 2, 4, 8], help="worker processes P")
    p.add_argument("--envs", type=int, default=4, help="envs a worker K")
    p.add_argument("--waves", type=int, default=3, help="waves of K episodes a worker")
    p.add_argument("--fixed-ms", type=float, default=50.0)
    p.add_argument("--row-ms", type=float, default=1.0)
    p.add_argument("--model-mib", type=int, default=256, help="the model's weights in memory, MiB")
    p.add_argument("--max-batch", type=int, default=64)
    p.add_argument("--max-wait-ms", type=float, nargs="+", default=[5.0, 25.0],
                   help="the batching server's T, one row each")
    args = p.parse_args()
    print(f"stand-in model: {args.fixed_ms:g} ms + {args.row_ms:g} ms a row, {args.model_mib} MiB "
          f"of weights; K = {args.envs} envs a worker, {args.waves} waves, {STEPS} steps in chunks of {HORIZON}; "
          f"--max-batch {args.max_batch}; simulator left out")
    batching = [f"T={t:g}" for t in args.max_wait_ms]
    print("| P x K | episodes | today's server ep/s | " + " | ".join(f"batching {b} ms ep/s | ratio" for b in batching)
          + " | worker (P copies) ep/s | peak RSS shared MiB | peak RSS worker MiB |")
    print("|---|---:|---:|" + "---:|---:|" * len(batching) + "---:|---:|---:|")
    lines = []
    for procs in args.procs:
        r = run(procs, args)
        eps = r["eps"]
        cells = " | ".join(f"{eps[b]:.1f} | {eps[b] / eps['serial']:.1f}x" for b in batching)
        print(f"| {procs} x {args.envs} | {r['episodes']} | {eps['serial']:.1f} | {cells} | {eps['worker']:.1f} | "
              f"{r['rss_shared_mb']:.0f} | {r['rss_worker_mb']:.0f} |", flush=True)
        lines += [f"P = {procs}, {b} ms: {r['summary'][b]}" for b in batching]
    print("batch sizes formed by the batching server (rows a call: calls):")
    for line in lines:
        print(f"  {line}")


if __name__ == "__main__":
    threading.current_thread().name = "bench"
    main()
