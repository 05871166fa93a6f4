"""Traced programs kept on disk (``jax.export``), so that a second process skips Python tracing as well as XLA.

JAX's persistent compilation cache (:mod:`.jax_cache`) saves XLA's work, but its key is the lowered program, so every
process still traces and lowers each program first, most of a second ``myriad bench --published-only``. This store
keeps each traced program as a serialised :class:`jax.export.Exported`; a later process
deserialises it and compiles ``jax.jit(exported.call)`` (an executable the compilation cache then has too), the
first process compiles the same thing, so both ask the compilation cache for the same key.

Only programs with a *key* are stored: a string that, with the argument shapes, says everything the traced closure
depends on (a spec-generated system's module source, a transcription's configuration, a solver's options; see
:func:`describe` and :func:`system_key`). Anything else, such as a learned model with its weights in the closure, has
no key and is traced as before. The file name also hashes this package's own source, the versions of JAX and the
libraries traced through, the float width and the device: a change to any of them is a different program. A program
that cannot be exported (a host callback, an unregistered pytree) is lowered the usual way and not stored. The store
(``<compilation cache folder>/programs``, see :mod:`.jax_cache`) is written atomically and safe to delete.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import logging
import os
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np

from ..atomic import atomic_write_bytes

__all__ = ["QUICK", "compiler_options", "describe", "lower", "program_folder", "register_namedtuple",
           "set_compiler_options", "set_program_folder", "signature", "system_key"]

log = logging.getLogger(__name__)
_FOLDER: Path | None = None
# Libraries whose code is traced into the programs (their versions are part of every file name).
_TRACED_LIBRARIES = ("jax", "jaxlib", "numpy", "diffrax", "equinox", "lineax", "optimistix")


# XLA's lowest backend (LLVM) optimisation, without its CPU fusion emitters: for programs that run once or for one
# solve, where compiling is most of the time (measurements: docs/notes/2026-12-05-benchmark-history.md).
QUICK = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
_COMPILER_OPTIONS: dict[str, Any] | None = None


def set_compiler_options(options: dict[str, Any] | None) -> None:
    """XLA options for every program this process compiles from now on (None: XLA's defaults). They are part of
    the compilation cache's key, so executables compiled with other options are never mixed up with these."""
    global _COMPILER_OPTIONS
    _COMPILER_OPTIONS = dict(options) if options else None


def compiler_options() -> dict[str, Any] | None:
    return None if _COMPILER_OPTIONS is None else dict(_COMPILER_OPTIONS)


def set_program_folder(folder: str | os.PathLike | None) -> None:
    """Store programs in ``folder`` (created on first write); None turns the store off."""
    global _FOLDER
    _FOLDER = None if folder is None else Path(folder)


def program_folder() -> Path | None:
    return _FOLDER


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """This package's Python source, the traced libraries' versions, the float width and the device kind."""
    import importlib.util

    digest = hashlib.sha256()
    for package in ("myriad.runtime", "myriad.compiler"):  # found, not imported: the compiler's imports cost 0.4 s
        root = Path(importlib.util.find_spec(package).origin).parent
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    for name in _TRACED_LIBRARIES:
        try:
            digest.update(f"{name}={metadata.version(name)}".encode())
        except metadata.PackageNotFoundError:
            digest.update(f"{name}=absent".encode())
    device = jax.devices()[0]
    digest.update(f"x64={jax.config.jax_enable_x64};{device.platform};{device.device_kind}".encode())
    return digest.hexdigest()


def describe(obj: Any) -> str | None:
    """A canonical text of a configuration object, or None when it is not made only of plain values.

    Plain: None, bools, ints, floats, strings, tuples and lists of plain values, and dataclasses of this package whose
    fields are plain (transcriptions, integrators, solver options). A float is written with ``repr`` (round-trips),
    an array or a callable is not plain: an object holding one cannot be keyed by its text.
    """
    if obj is None or isinstance(obj, (bool, int, str)):
        return repr(obj)
    if isinstance(obj, float):
        return repr(float(obj))
    if isinstance(obj, (tuple, list)):
        parts = [describe(v) for v in obj]
        return None if None in parts else f"[{','.join(parts)}]"
    cls = type(obj)
    if dataclasses.is_dataclass(obj) and cls.__module__.startswith("myriad."):
        parts = []
        for field in dataclasses.fields(obj):
            text = describe(getattr(obj, field.name))
            if text is None:
                return None
            parts.append(f"{field.name}={text}")
        return f"{cls.__module__}.{cls.__qualname__}({','.join(parts)})"
    return None


def system_key(system: Any) -> str | None:
    """The source of a spec-generated system's module (shipped or loaded from a spec file), hashed; None for any other
    system (a learned model, a hand-written subclass), whose behaviour its source file need not pin down."""
    return _module_key(type(system).__module__)


@functools.lru_cache(maxsize=None)
def _module_key(module: str) -> str | None:
    # Once per module and process: the code in memory is what was imported, whatever the file says later.
    if not (module.startswith("myriad.runtime.systems.") or module.startswith("myriad_user_systems.")):
        return None
    import sys

    path = getattr(sys.modules.get(module), "__file__", None)
    if path is None:
        return None
    return f"system:{hashlib.sha256(Path(path).read_bytes()).hexdigest()}"


def signature(args: tuple) -> tuple:
    """The arguments' tree structure and each leaf's shape and dtype: what one compiled executable serves."""
    leaves, treedef = jax.tree.flatten(args)
    return treedef, tuple((np.shape(x), x.dtype if hasattr(x, "dtype") else np.result_type(x)) for x in leaves)


# NamedTuples that cross a stored program's boundary: jax.export must know them by a stable name. Each type registers
# itself where it is defined (register_namedtuple), so this module names none of them (no import of solvers or
# core types from the infrastructure); they are handed to jax.export on the next lower(), once each.
_PENDING: list[type] = []
_REGISTERED: set[str] = set()


def register_namedtuple(cls: type) -> type:
    """Let ``cls`` (a NamedTuple) cross a stored program's boundary, under the name ``myriad.<qualname>``.

    Call it where the type is defined (usable as a class decorator); returns ``cls``."""
    _PENDING.append(cls)
    return cls


def _register_pending() -> None:
    from jax import export

    while _PENDING:
        cls = _PENDING.pop()
        name = f"myriad.{cls.__qualname__}"
        if name not in _REGISTERED:  # a module imported twice (a reload) defines the type again: the first one stays
            export.register_namedtuple_serialization(cls, serialized_name=name)
            _REGISTERED.add(name)


def lower(jitted: Callable, key: str | None, args: tuple) -> Any:
    """``jitted.lower(*args)``, through the store when it is on and ``key`` is given (see the module docstring)."""
    if key is None or _FOLDER is None:
        return jitted.lower(*args)
    from jax import export

    try:
        _register_pending()
        name = hashlib.sha256(f"{key}|{signature(args)}|{_code_fingerprint()}".encode()).hexdigest()
        path = _FOLDER / f"{name[:40]}.jaxexport"
        exported = None
        if path.exists():
            try:
                exported = export.deserialize(bytearray(path.read_bytes()))
            except Exception as exc:  # a truncated or foreign file: export it again below
                log.debug("program store: %s unreadable (%s); exporting again", path, exc)
        if exported is None:
            exported = export.export(jitted)(*args)
            blob = exported.serialize()
            _FOLDER.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(path, blob)
        return jax.jit(exported.call).lower(*args)
    except Exception as exc:  # not exportable (e.g. a host callback): the usual lowering, nothing stored
        log.debug("program store: %s not stored (%s)", key, exc)
        return jitted.lower(*args)
