"""Load a system by name (the shipped, committed modules), a peer problem as ``peers/<name>`` (the committed modules
of ``specs/peers/``, generated into ``runtime/systems/peers/``), or compile any spec path on the fly.

Specs outside the repository are compiled with :mod:`myriad.compiler` into a cache folder keyed by the spec's content
and the compiler's own source, so editing either recompiles and nothing stale is ever imported.
"""

from __future__ import annotations

import difflib
import functools
import hashlib
import importlib.util
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from . import systems as _registry
from .atomic import atomic_write_text

if TYPE_CHECKING:  # not imported: compiled_spec runs without JAX (the cold start's `myriad solve`, issue 31)
    from .system import System

__all__ = ["load", "compiled_spec", "spec_build_dir", "PEER_PREFIX"]

PEER_PREFIX = "peers/"  # load("peers/goddard_rocket"): a problem of the peer collection (specs/peers/README.md)

_loaded: dict[str, System] = {}


def spec_build_dir() -> Path:
    """``$MYRIAD_CACHE``/systems or ``~/.cache/myriad/systems``: where specs loaded by path are compiled (not JAX's
    compilation cache, :func:`myriad.runtime.compilation.jax_cache.compilation_cache_dir`)."""
    base = os.environ.get("MYRIAD_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "myriad")
    return Path(base) / "systems"


@functools.cache  # read the compiler's sources once per process, not on every load by path
def _compiler_fingerprint() -> str:
    # Found, not imported: a spec compiled earlier loads without importing the compiler (sympy).
    root = Path(importlib.util.find_spec("myriad.compiler").origin).parent
    h = hashlib.sha256()
    for p in sorted([*root.glob("*.py"), *root.glob("templates/*.jinja")]):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def load(target: str | os.PathLike) -> System:
    """The system for a shipped name (``"pendulum"``), a peer problem (``"peers/hypersensitive"``, or its bare name
    where no shipped system has it) or a spec file path (``"my/spec.yaml"``). Names match case-insensitively where
    that is unambiguous.

    Raises:
        KeyError: an unknown name that is not a file either (with the closest names), or a missing spec file.
        myriad.compiler.SpecError: the spec at the path is invalid (the message points into the file).
    """
    text = os.fspath(target)
    path = Path(text)
    if text not in _registry.MODULES and not path.is_file():
        text = _resolve_name(text)
    if text in _registry.MODULES and not text.endswith((".yaml", ".yml")):
        return _registry.get(text)
    if text.startswith(PEER_PREFIX) and not path.is_file():
        from .systems import peers

        return peers.get(text[len(PEER_PREFIX):])
    key = _spec_key(text)
    if key in _loaded:
        return _loaded[key]
    module_path = compiled_spec(text, key)
    module_name = f"myriad_user_systems.{module_path.stem}_{key[:16]}"
    spec = importlib.util.spec_from_file_location(module_name, module_path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    spec.loader.exec_module(module)
    _loaded[key] = module.SYSTEM
    return module.SYSTEM


def _spec_key(text: str) -> str:
    # The generated module depends on the spec's bytes, the compiler and the path it names (relative to the working
    # folder where inside it): all in the key, so a module found under it is what compiling again would write.
    where = f"{os.path.abspath(text)}\0{os.getcwd()}\0{_compiler_fingerprint()}"
    return hashlib.sha256(Path(text).read_bytes() + where.encode()).hexdigest()


def compiled_spec(spec: str | os.PathLike, key: str | None = None) -> Path:
    """The generated module of the spec file ``spec`` in :func:`spec_build_dir`, compiled there first unless it is
    (what :func:`load` imports). Imports no JAX: a `myriad solve` runs it in a second process while it imports JAX.

    Raises:
        myriad.compiler.SpecError: the spec is invalid."""
    text = os.fspath(spec)
    folder = spec_build_dir() / (key or _spec_key(text))[:32]
    built = sorted(folder.glob("*.py"))  # written atomically: a module there is whole
    if len(built) == 1:
        return built[0]
    from myriad.compiler import compile_file  # the compiler (sympy) is only needed to compile a spec

    compiled = compile_file(Path(text))
    module_path = folder / f"{compiled.name}.py"
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_text(module_path, compiled.text)
    return module_path


def _names() -> dict[str, str]:
    """Every name :func:`load` takes without a file: the shipped systems, then the peers by bare name (where no
    shipped system has it) and as ``peers/NAME``; each mapped to its canonical form."""
    from .systems import peers

    names = {n: n for n in _registry.NAMES}
    for n in peers.NAMES:
        names.setdefault(n, PEER_PREFIX + n)
        names[PEER_PREFIX + n] = PEER_PREFIX + n
    return names


def _resolve_name(text: str) -> str:
    """The canonical name of ``text`` (a name, not an existing file); ``KeyError`` with the fix where there is none."""
    names = _names()
    if text in names:
        return names[text]
    folded = {names[n] for n in names if n.lower() == text.lower()}
    if len(folded) == 1:
        return folded.pop()
    is_path = text.endswith((".yaml", ".yml")) or os.sep in text or bool(os.altsep and os.altsep in text)
    if text.startswith(PEER_PREFIX) and not text.endswith((".yaml", ".yml")):
        name, peers = text[len(PEER_PREFIX):], [n[len(PEER_PREFIX):] for n in names if n.startswith(PEER_PREFIX)]
        close = difflib.get_close_matches(name, peers, n=3)
        hint = f"did you mean {' or '.join(PEER_PREFIX + n for n in close)}? " if close else ""
        raise KeyError(f"unknown peer problem {name!r}; {hint}the peer collection: {', '.join(peers)}")
    if is_path:
        raise KeyError(f"file not found: {text}")
    close = difflib.get_close_matches(text, [n for n in names if not n.startswith(PEER_PREFIX)], n=3)
    if close:
        hint = f"did you mean {' or '.join(close)}?"
    else:
        peers = ", ".join(n for n in names if n.startswith(PEER_PREFIX))
        hint = f"shipped: {', '.join(_registry.NAMES)}; peers: {peers}"
    raise KeyError(f"{text!r} is neither a shipped system, a peer problem ({PEER_PREFIX}NAME) nor a spec file; {hint}")
