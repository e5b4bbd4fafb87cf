"""The one reader of ``"package.module:attr"`` names, and of ``KEY=VALUE`` arguments (``-a``, ``-e``).
Policies, backbones, question pools, candidate builders, experts and audit readers are named by such
strings and imported only when used (a leaf: it imports nothing of the pack)."""
from __future__ import annotations

import importlib
import json
from typing import Any


def resolve(spec: str, what: str = "object", *, must_call: bool = True) -> Any:
    """``"pkg.mod:attr.sub"`` -> the object it names (``attr`` may be dotted).

    Errors are one line that names ``what`` and the part of the spec that failed: ValueError (not
    ``module:attr``), ImportError (the module does not import), AttributeError (no such attribute),
    TypeError (``must_call`` and the object is not callable)."""
    module_name, _, attr = spec.partition(":") if isinstance(spec, str) else ("", "", "")
    if not module_name or not attr:
        raise ValueError(f"{what} spec {spec!r} must be 'package.module:factory' with both parts non-empty")
    try:
        obj: Any = importlib.import_module(module_name)
    except ImportError as err:
        raise ImportError(f"{what} spec {spec!r}: cannot import module {module_name!r}: {err}") from err
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise AttributeError(f"{what} spec {spec!r}: module {module_name!r} has no attribute {attr!r}") from None
    if must_call and not callable(obj):
        raise TypeError(f"{what} spec {spec!r}: {attr!r} is not callable")
    return obj


def key_values(items: list[str], what: str) -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}``: each VALUE parsed as JSON, else kept as a string.
    An item without ``KEY=`` is a ValueError naming ``what`` (the flag)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{what} {item!r} must look like KEY=VALUE")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out
