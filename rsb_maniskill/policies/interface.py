"""The policy interface of the evaluator: what a policy is, and how its outputs are read.

A policy is anything with ``reset(instruction, obs)`` and ``act(obs) -> (T, action_dim)`` chunk.
The runner calls ``reset`` once per episode with the instruction (after the instruction-mode
ablation) and the first observation, then ``act``; it executes the T actions of the chunk in
order and calls ``act`` again with the newest observation. Observations are the single-env
observation as numpy arrays in the env's nested dict layout (leading env dim removed).

A policy that talks returns ``{"actions": chunk, "text": str}`` instead of the bare chunk (its
chain of thought, say): the record keeps the episode's text and the option it states
(``statements.py``). The batched form's mapping holds one text per env (None where it has none).

The optional batched form (:class:`BatchedPolicy`) drives the B parallel envs of ``--num-envs``
with one object: ``reset_batch(instructions, obs)`` and ``act_batch(obs, envs) -> (len(envs), T,
action_dim)``, observations keeping their leading env dim. A policy that has it (the remote
client: one request per step for all envs) is built once; one without it is built once per env
and batched by :class:`PerEnvPolicies`. The single-env form is what everything else uses.

A policy's episode must be a function of its seed: the same seed gives the same actions whatever
``--num-envs``, ``--num-procs`` and the order the episodes run in (a worker runs any share of the
seeds, and a resumed run starts mid-way). A policy that draws random numbers therefore reseeds per
episode: ``reset`` may take a keyword ``seed`` (``reset_batch``: ``seeds``, one per env), the
episode's seed, and the runner passes it where the method accepts it (:func:`reset_policy`); a
generator seeded once at construction and drawn across episodes breaks the rule (the reference
policies reseed; ``tests/acceptance/test_faults.py`` checks K = 1 against K = 2).

A policy that misbehaves (raises in ``reset`` / ``act``, or returns what the env cannot take)
raises :class:`~rsb_maniskill.policies.errors.PolicyError`: one line naming the policy,
the episode and what came back, its traceback kept for ``rsb --debug``.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from rsb_maniskill.policies.errors import PolicyError, blame_policy, shown


@runtime_checkable
class Policy(Protocol):
    """What ``rsb eval`` needs from a policy. An optional ``name`` attribute labels its records."""

    def reset(self, instruction: str, obs: dict) -> None:
        """Start an episode: ``instruction`` is the text the policy may use ("" in blank mode). It may
        also take ``seed`` (a keyword: the episode's seed), to reseed what it draws at random."""

    def act(self, obs: dict) -> Any:
        """Action chunk of shape (T, action_dim), T >= 1, executed in order before the next call;
        or ``{"actions": chunk, "text": str}``."""

    # Served to many envs (``rsb serve``, ``rsb eval --policy-process shared``), each env gets its own
    # object made from the policy as built: ``fork()`` where the policy defines it (returning a new
    # policy for another env that shares the weights and nothing that changes in an episode), else a
    # deep copy whose torch modules are shared by reference. Define ``fork`` when that copy is wrong
    # (weights outside a torch module, episode state inside one) or cannot be made (a lock, a socket).


@runtime_checkable
class BatchedPolicy(Protocol):
    """The optional batched form: one object for B parallel envs (rows of batched observations).

    To be served to many clients in one batch (``rsb serve``, ``rsb eval --policy-process shared``) it
    also needs ``reset_envs(instructions, obs, envs, seeds=None)``: start episodes in the envs
    ``envs`` only (env ``envs[i]`` gets ``instructions[i]``, the first observation ``obs`` row i, and
    ``seeds[i]`` when the method takes ``seeds``), the other envs going on with theirs. There an env
    index is a slot of the server's table (one per env of every client, reused after a client leaves:
    any whole numbers from 0, not only ``range(B)``), and ``act_batch`` gets rows of many clients. A
    batched policy without ``reset_envs`` is served by its single-env form (``reset`` / ``act``), or
    refused: a ``reset_batch`` over every env would restart the other clients' episodes.
    """

    def reset_batch(self, instructions: Sequence[str], obs: dict) -> None:
        """Start B episodes: env i gets ``instructions[i]``; ``obs`` rows are the envs' first observations.
        It may also take ``seeds`` (a keyword: env i's episode seed ``seeds[i]``)."""

    def act_batch(self, obs: dict, envs: Sequence[int]) -> Any:
        """Chunks for the envs ``envs`` (indices into the reset's B), ``obs`` holding their rows in that
        order: a (len(envs), T, action_dim) array, or a list of (T_i, action_dim) chunks; or
        ``{"actions": chunks, "text": [one str or None per env]}``."""


def is_batched(policy: Any) -> bool:
    return callable(getattr(policy, "reset_batch", None)) and callable(getattr(policy, "act_batch", None))


def takes_keyword(method: Any, name: str) -> bool:
    """Whether ``method`` names the keyword ``name`` (not merely ``**kwargs``, which a policy may pass
    on to a model that does not take it)."""
    import inspect

    try:
        params = inspect.signature(method).parameters.values()
    except (TypeError, ValueError):  # a builtin or a C method without a signature: not given
        return False
    return any(p.name == name and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) for p in params)


def reset_policy(policy: Any, instruction: str, obs: Any, seed: int) -> None:
    """``policy.reset(instruction, obs)``, with ``seed=`` (the episode's) where ``reset`` takes it."""
    if takes_keyword(policy.reset, "seed"):
        policy.reset(instruction, obs, seed=seed)
    else:
        policy.reset(instruction, obs)


def reset_policies(policy: Any, instructions: Sequence[str], obs: Any, seeds: Sequence[int]) -> None:
    """``policy.reset_batch(instructions, obs)``, with ``seeds=`` where ``reset_batch`` takes it."""
    if takes_keyword(policy.reset_batch, "seeds"):
        policy.reset_batch(instructions, obs, seeds=list(seeds))
    else:
        policy.reset_batch(instructions, obs)


def obs_rows(obs: Any, rows: Sequence[int]) -> Any:
    """Rows ``rows`` of a batched (nested) observation, as numpy with the leading dim kept."""
    if isinstance(obs, dict):
        return {k: obs_rows(v, rows) for k, v in obs.items()}
    if hasattr(obs, "detach"):
        obs = obs.detach().cpu().numpy()
    return np.asarray(obs)[list(rows)]


class PerEnvPolicies:
    """The batched form over one single-env policy per env (``--num-envs`` for a policy without it).

    What goes wrong in one env's call is the user's ``reset`` / ``act`` (the methods they wrote), in
    that env: the :class:`PolicyError` says so and carries ``row``, the env's position in the call,
    which the loop turns into its seed. ``action_dim``: each chunk is checked as ``act``'s."""

    def __init__(self, policies: Sequence[Any], action_dim: int | None = None) -> None:
        self.policies = list(policies)
        self.name = policy_name(self.policies[0]) if self.policies else "policy"
        self.action_dim = action_dim

    def reset_batch(self, instructions: Sequence[str], obs: dict, seeds: Sequence[int] | None = None) -> None:
        if len(instructions) > len(self.policies):
            raise ValueError(f"need one policy per env: {len(instructions)} envs, {len(self.policies)} policies")
        for i, text in enumerate(instructions):
            with _in_row("reset", i):
                if seeds is None:
                    self.policies[i].reset(text, _row(obs, i))
                else:
                    reset_policy(self.policies[i], text, _row(obs, i), seeds[i])

    def act_batch(self, obs: dict, envs: Sequence[int]) -> Any:
        outs = []
        for k, e in enumerate(envs):
            with _in_row("act", k):
                out = self.policies[e].act(_row(obs, k))
                actions, text = split_output(out)
                outs.append({"actions": as_chunk(actions, self.action_dim), "text": text} if text is not None
                            else as_chunk(actions, self.action_dim))
        return join_outputs(outs)


@contextmanager
def _in_row(call: str, row: int) -> Iterator[None]:
    """One env's ``call`` of :class:`PerEnvPolicies`: its error names ``call`` and carries ``row``
    (the policy and the episode are named by the loop around it)."""
    try:
        with blame_policy(call, policy=None, where=None):
            yield
    except PolicyError as err:
        err.row = row if getattr(err, "row", None) is None else err.row
        raise


def _row(obs: Any, i: int) -> Any:
    if isinstance(obs, dict):
        return {k: _row(v, i) for k, v in obs.items()}
    return np.asarray(obs)[i]


def as_chunks(actions: Any, n: int, action_dim: int | None = None) -> list[np.ndarray]:
    """Check a batched policy's output: ``n`` chunks, each as :func:`as_chunk` wants it."""
    if isinstance(actions, np.ndarray) and actions.ndim != 3:
        raise PolicyError(f"act_batch must return shape (envs, T, action_dim), got shape {actions.shape}")
    if isinstance(actions, (str, bytes)) or not isinstance(actions, (np.ndarray, Sequence)):
        raise PolicyError(f"act_batch returned {shown(actions)}; return an array of shape (envs, T, action_dim) "
                          "or a list of (T, action_dim) chunks")
    chunks = list(actions)
    if len(chunks) != n:
        raise PolicyError(f"act_batch returned {len(chunks)} chunks for {n} envs")
    return [as_chunk(c, action_dim, "act_batch") for c in chunks]


def _actions(out: Mapping, method: str) -> Any:
    if "actions" not in out:
        raise PolicyError(f"{method} returned a mapping without 'actions' (keys: {sorted(map(str, out))}); "
                          "return the actions, or {'actions': ..., 'text': ...}")
    return out["actions"]


def split_output(out: Any) -> tuple[Any, str | None]:
    """A policy's ``act`` output as (actions, text): the bare actions give no text (None)."""
    if not isinstance(out, Mapping):
        return out, None
    text = out.get("text")
    if text is not None and not isinstance(text, str):
        raise PolicyError(f"act returned 'text' of type {type(text).__name__}; it must be a str")
    return _actions(out, "act"), text


def split_outputs(out: Any, n: int) -> tuple[Any, list[str | None]]:
    """A batched policy's output as (actions, one text or None per env)."""
    if not isinstance(out, Mapping):
        return out, [None] * n
    texts = out.get("text")
    if texts is None:
        return _actions(out, "act_batch"), [None] * n
    if isinstance(texts, str) or not isinstance(texts, Sequence) or len(texts) != n \
            or not all(t is None or isinstance(t, str) for t in texts):
        raise PolicyError(f"act_batch must return 'text' as a list of {n} str (or None), one per env; "
                          f"got {type(texts).__name__}")
    return _actions(out, "act_batch"), list(texts)


def join_outputs(outs: Sequence[Any]) -> Any:
    """Single-env outputs of several envs as one batched output (a mapping when any has text)."""
    pairs = [split_output(o) for o in outs]
    if all(text is None for _, text in pairs):
        return [a for a, _ in pairs]
    return {"actions": [a for a, _ in pairs], "text": [t for _, t in pairs]}


def env_action_space(env: Any) -> Any:
    """The action space of one env of ``env`` (ManiSkill's ``single_action_space`` when batched)."""
    return getattr(env.unwrapped, "single_action_space", None) or env.action_space


def policy_name(policy: Any) -> str:
    """Label for records and tables: the policy's ``name`` attribute, else its class name."""
    name = getattr(policy, "name", None)
    return str(name) if name else type(policy).__name__


def _complex_dtype(actions: Any) -> str | None:
    """The dtype of complex actions (a numpy or torch array, a list of complex numbers), else None."""
    dtype = getattr(actions, "dtype", None)
    if isinstance(dtype, np.dtype):
        return str(dtype) if dtype.kind == "c" else None
    if dtype is not None:  # a torch tensor's
        return str(dtype) if getattr(dtype, "is_complex", False) else None
    if isinstance(actions, (list, tuple)):
        try:
            found = np.asarray(actions)
        except (TypeError, ValueError):
            return None
        return str(found.dtype) if np.iscomplexobj(found) else None
    return None


def as_chunk(actions: Any, action_dim: int | None = None, method: str = "act") -> np.ndarray:
    """Check and normalise a policy's output to a float (T, action_dim) array.

    A single action of shape (action_dim,) is accepted as a chunk of one. Errors (PolicyError) say
    what came back, since a wrong output from a user policy is the most common integration bug.
    """
    want = f"an array of shape (T, {action_dim or 'action_dim'}) with T >= 1"
    if actions is None:
        raise PolicyError(f"{method} returned None; return {want}")
    kind = _complex_dtype(actions)
    if kind is not None:  # numpy would drop the imaginary part with a ComplexWarning; the env cannot clamp it
        raise PolicyError(f"{method} returned complex actions (dtype {kind}); return {want} of real numbers")
    if isinstance(actions, np.ndarray):
        a = actions
    else:
        try:
            a = np.asarray(actions, dtype=np.float64)
        except (TypeError, ValueError):
            raise PolicyError(f"{method} returned {shown(actions)}, not numbers; return {want}") from None
    if a.ndim == 1:
        a = a[None]
    if a.ndim == 2 and a.shape[0] == 0:
        raise PolicyError(f"{method} returned an empty chunk (shape {a.shape}); return {want}")
    if a.ndim != 2:
        raise PolicyError(f"{method} must return {want}, got shape {a.shape}")
    if action_dim is not None and a.shape[1] != action_dim:
        raise PolicyError(f"{method} returned actions of dim {a.shape[1]} (chunk shape {a.shape}); the env takes "
                          f"{action_dim} numbers an action (its control mode's action space)")
    if not np.issubdtype(a.dtype, np.number):
        raise PolicyError(f"{method} returned an array of dtype {a.dtype}; return {want} of numbers")
    bad = ~np.isfinite(a)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise PolicyError(f"{method} returned NaN or inf actions ({int(bad.sum())} of {a.size} numbers, the first "
                          f"at action {row}, index {col}: {a[row, col]})")
    return a
