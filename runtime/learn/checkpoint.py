"""Checkpoints of a learner's run: parameters, optimiser state, PRNG key, step and the best-so-far, written atomically.

One checkpoint is one ``.npz`` file (NumPy arrays only, read back with ``allow_pickle=False``): the array leaves of
the trees in ``jax.tree`` order, the key, the best value and the history, and ``meta``, a JSON string (identities,
the leaves' key paths, shapes and dtypes, ``extra``). Its JSON copy beside it is for people and tools; the copy
inside the ``.npz`` is the authoritative one (the pair cannot be replaced in one atomic step).

Restoring needs templates, the pytrees a fresh start would build: their structure is the one thing an ``.npz``
cannot hold without pickling code. Floats round-trip bit for bit: a resumed fit continues exactly where it stopped.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..atomic import atomic_open, atomic_write_text

__all__ = ["Checkpoint", "CheckpointMismatch", "load_checkpoint", "save_checkpoint"]

# The format's name predates the learning kit; kept, so that checkpoints written before it still resume.
FORMAT, VERSION = "myriad.sysid.checkpoint", 1
_TREES = ("theta", "opt_state", "best_theta")


class CheckpointMismatch(ValueError):
    """The checkpoint belongs to another dataset, configuration or parameter structure."""


class Checkpoint(NamedTuple):
    """A restored checkpoint (see :func:`load_checkpoint`); ``extra`` holds the caller's integers."""

    theta: Any
    opt_state: Any
    key: Any
    epoch: int
    best_theta: Any
    best_val: float
    history: list
    dataset_id: str
    config_id: str
    extra: dict


def _is_data(leaf: Any) -> bool:
    return isinstance(leaf, (jax.Array, np.ndarray, np.generic, int, float, complex, bool))


def _leaves(tree: Any) -> list[tuple[str, np.ndarray]]:
    """(key path, host array) of every data leaf (non-array leaves, e.g. functions, belong to the template)."""
    flat, _ = jax.tree_util.tree_flatten_with_path(tree)
    return [(jax.tree_util.keystr(p), np.asarray(v)) for p, v in flat if _is_data(v)]


def save_checkpoint(path: str | os.PathLike, *, theta: Any, opt_state: Any, key: Any, epoch: int, best_theta: Any,
                    best_val: float, history: list, dataset_id: str, config_id: str, config: dict | None = None,
                    extra: dict | None = None) -> Path:
    """Write a checkpoint to ``path`` (a ``.npz``, returned) and its JSON copy to ``path.with_suffix(".json")``,
    atomically: the array leaves of the pytrees, a ``jax.random`` key, the completed epochs, the best validation loss
    (may be inf), the history ``[(epoch, train_loss, val_loss), ...]``, the data's and the run's identities checked on
    load (``config``: the run's description, to say *what* differs) and ``extra`` scalars the caller needs back."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"save_checkpoint: the path must end in .npz, got {str(path)!r}")
    if jax.dtypes.issubdtype(getattr(key, "dtype", None), jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    arrays: dict[str, np.ndarray] = {}
    leaves_meta = {}
    for name, tree in zip(_TREES, (theta, opt_state, best_theta)):
        leaves = _leaves(tree)
        leaves_meta[name] = [[p, list(a.shape), a.dtype.str] for p, a in leaves]
        arrays.update({f"{name}.{i}": a for i, (_, a) in enumerate(leaves)})
    arrays["key"] = np.asarray(key)
    arrays["best_val"] = np.asarray(best_val, dtype=np.float64)
    arrays["history"] = np.asarray([tuple(map(float, row)) for row in history], dtype=np.float64).reshape(-1, 3)
    meta = {"format": FORMAT, "version": VERSION, "epoch": int(epoch), "dataset_id": dataset_id,
            "config_id": config_id, "config": config, "extra": dict(extra or {}), "leaves": leaves_meta}
    text = json.dumps(meta, indent=1, sort_keys=True, allow_nan=False)  # serialise before writing anything
    arrays["meta"] = np.asarray(text)  # a unicode array: loads without pickle
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as f:
        f.write(buf.getvalue())
    atomic_write_text(path.with_suffix(".json"), text + "\n")
    return path


def _restore(name: str, template: Any, stored: list, z: Any, path: Path) -> Any:
    flat, treedef = jax.tree_util.tree_flatten_with_path(template)
    want = [(jax.tree_util.keystr(p), np.shape(v), np.asarray(v).dtype.str) for p, v in flat if _is_data(v)]
    got = [(p, tuple(s), d) for p, s, d in stored]
    if len(want) != len(got):
        raise CheckpointMismatch(f"{path}: {name} has {len(got)} array leaves, the template {len(want)}: a different "
                                 f"model or optimiser (checkpoint {[g[0] for g in got]}, now {[w[0] for w in want]})")
    for (wp, ws, wd), (gp, gs, gd) in zip(want, got):
        if (wp, tuple(ws), wd) != (gp, gs, gd):
            raise CheckpointMismatch(f"{path}: {name} leaf {gp} is {gs} {gd} in the checkpoint but the template has "
                                     f"{wp} {tuple(ws)} {wd}: a different model or optimiser")
    it = iter(range(len(got)))
    # jnp.asarray of a host array is a committed, strongly typed leaf: what a fresh init builds.
    leaves = [jnp.asarray(z[f"{name}.{next(it)}"]) if _is_data(v) else v for _, v in flat]
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _config_diff(old: dict | None, new: dict | None) -> str:
    if not isinstance(old, dict) or not isinstance(new, dict):
        return ""
    keys = sorted(set(old) | set(new))
    diffs = [f"{k}: {old.get(k)!r} in the checkpoint, {new.get(k)!r} now" for k in keys if old.get(k) != new.get(k)]
    return "; differing: " + "; ".join(diffs) if diffs else ""


def load_checkpoint(path: str | os.PathLike, template: Any, *, dataset_id: str | None = None,
                    config_id: str | None = None, config: dict | None = None) -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint` against ``template``, a mapping with ``"theta"`` and
    ``"opt_state"``: fresh pytrees of the right structure (``best_theta`` is restored against ``"theta"``).

    ``dataset_id`` and ``config_id``, when given, must equal the stored ones (``config``, this run's description,
    names the fields that differ); every stored leaf must match its template leaf's key path, shape and dtype. Else
    :class:`CheckpointMismatch`; ``FileNotFoundError`` when there is no such file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"load_checkpoint: {str(path)!r} does not exist")
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        if meta.get("format") != FORMAT or meta.get("version") != VERSION:
            raise CheckpointMismatch(f"{path}: not a {FORMAT} version {VERSION} file (format {meta.get('format')!r}, "
                                     f"version {meta.get('version')!r})")
        if dataset_id is not None and meta["dataset_id"] != dataset_id:
            raise CheckpointMismatch(
                f"{path}: the checkpoint was written for dataset {meta['dataset_id'][:16]}, but this fit's dataset is "
                f"{dataset_id[:16]} (another system, seed, sampling or trajectories): resume only on the same data, "
                f"or start afresh (resume=False, or another checkpoint_dir)")
        if config_id is not None and meta["config_id"] != config_id:
            raise CheckpointMismatch(
                f"{path}: the checkpoint was written with configuration {meta['config_id'][:16]}, but this fit's is "
                f"{config_id[:16]}{_config_diff(meta.get('config'), config)}: resume with the same settings (only "
                f"epochs, patience, tol and checkpoint_every may change), or start afresh")
        theta = _restore("theta", template["theta"], meta["leaves"]["theta"], z, path)
        opt_state = _restore("opt_state", template["opt_state"], meta["leaves"]["opt_state"], z, path)
        best_theta = _restore("best_theta", template["theta"], meta["leaves"]["best_theta"], z, path)
        key = jnp.asarray(z["key"])
        best_val = float(z["best_val"])
        history = [(int(e), float(a), float(b)) for e, a, b in z["history"]]
    return Checkpoint(theta=theta, opt_state=opt_state, key=key, epoch=int(meta["epoch"]), best_theta=best_theta,
                      best_val=best_val, history=history, dataset_id=meta["dataset_id"],
                      config_id=meta["config_id"], extra=meta.get("extra", {}))
