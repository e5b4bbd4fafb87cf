"""Policies: the interface the evaluator speaks (``interface.py``), the table of built-ins and the
loader (``registry.py``), the reference policies (``reference.py``), the errors a misbehaving policy
raises (``errors.py``) and policies over the network (``remote/``, one table of wire protocols).

Add a policy with one ``register_policy(name, "package.module:factory")`` call, or name its factory
directly: ``rsb eval package.module:factory``. Importing this package loads no policy: the reference
policies (``rsb_maniskill.policies.reference``) and the remote clients load when they are named.
"""
from __future__ import annotations

from rsb_maniskill.policies.errors import PolicyError
from rsb_maniskill.policies.interface import BatchedPolicy, PerEnvPolicies, Policy, as_chunk, policy_name
from rsb_maniskill.policies.registry import POLICIES, PolicySpec, builtin_policies, load_policy, register_policy

__all__ = [
    "BatchedPolicy", "POLICIES", "PerEnvPolicies", "Policy", "PolicyError", "PolicySpec", "as_chunk",
    "builtin_policies", "load_policy", "policy_name", "register_policy",
]
