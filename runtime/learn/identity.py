"""A run's identity: what fixes its sequence of iterates, as a JSON description and its SHA-256.

A checkpoint stores both; a resume recomputes them and refuses to continue another run, naming the fields that
differ. The description must not depend on the process: a callable is known by its qualified name, never by a
``repr`` that carries a memory address, or every resume would look like another configuration.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any

import jax
import numpy as np

__all__ = ["arrays_id", "describe", "digest", "optimizer_identity", "tree_id"]


def _is_optax(v: Any) -> bool:
    return not isinstance(v, type) and callable(getattr(v, "init", None)) and callable(getattr(v, "update", None))


def describe(v: Any) -> Any:
    """A JSON-ready, process-independent description of a configuration value: plain values as they are, sequences
    as lists, a dataclass (a solver, a nested configuration) by its type and fields, an optax transformation by its
    ``init`` function's name (its closure holds the learning rate, which a name cannot show: resume with the same
    object), any other callable by its qualified name, anything else by ``repr``."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if _is_optax(v):  # before sequences: a transformation is a NamedTuple
        return describe(v.init)
    if isinstance(v, (tuple, list)):
        return [describe(x) for x in v]
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {"type": type(v).__name__, **{f.name: describe(getattr(v, f.name)) for f in dataclasses.fields(v)}}
    if callable(v):
        return f"{getattr(v, '__module__', '?')}.{getattr(v, '__qualname__', type(v).__name__)}"
    return repr(v)


def optimizer_identity(optimizer: Any) -> dict:
    """``{"adam": learning_rate}`` for a learning rate (the learners' shorthand for Adam), else ``{"custom": name of
    its init}``: a custom transformation is also checked by its state's leaves when a checkpoint is restored."""
    if isinstance(optimizer, float):
        return {"adam": optimizer}
    return {"custom": describe(optimizer.init)}


def digest(description: dict) -> str:
    """The SHA-256 of a description (JSON with sorted keys: the same description, the same identity)."""
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()


def arrays_id(head: str, arrays: Any) -> str:
    """SHA-256 of ``head`` then each array's shape and little-endian float64 bytes (data a run read: an expert)."""
    h = hashlib.sha256(head.encode())
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a), dtype="<f8")
        h.update(f"{a.shape}".encode() + a.tobytes())
    return h.hexdigest()


def tree_id(tree: Any) -> str:
    """A SHA-256 of a pytree's structure and float64 leaves (given starting parameters)."""
    return arrays_id(str(jax.tree.structure(tree)), jax.tree.leaves(tree))
