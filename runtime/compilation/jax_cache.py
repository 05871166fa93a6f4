"""JAX's persistent compilation cache in a user folder: what every ``myriad`` command and sweep worker turns on.

A second process that compiles the same program (same NLP, shapes, JAX version and device) reads the executable from
the folder instead of running XLA again. The folder is ``$MYRIAD_JAX_CACHE`` if set, else ``~/.cache/myriad/jax``;
it is safe to delete at any time (the next compilation refills it). ``MYRIAD_JAX_CACHE=off`` (or ``none``, ``0``, an
empty value) turns it off, as ``myriad --no-cache`` does.

Its subfolder ``programs/`` holds the traced programs themselves (:mod:`.programs`), so that a second
process skips Python tracing too.
"""

from __future__ import annotations

import os

from . import programs

__all__ = ["DEFAULT_CACHE_DIR", "ENV_VAR", "compilation_cache_dir", "enable_compilation_cache"]

DEFAULT_CACHE_DIR = "~/.cache/myriad/jax"
ENV_VAR = "MYRIAD_JAX_CACHE"
_OFF = ("", "0", "off", "none", "false", "no")


def compilation_cache_dir(requested: str | None = None) -> str | None:
    """The folder to use: ``requested`` if given, else ``$MYRIAD_JAX_CACHE``, else the default; None when turned off."""
    if requested is None:
        requested = os.environ.get(ENV_VAR, DEFAULT_CACHE_DIR)
    if requested.strip().lower() in _OFF:
        return None
    return os.path.abspath(os.path.expanduser(requested))


def enable_compilation_cache(requested: str | None = None) -> str | None:
    """Point JAX's persistent compilation cache at :func:`compilation_cache_dir` unless this process already has one.

    JAX reads the setting once, at its first compilation, so a folder already chosen (``JAX_COMPILATION_CACHE_DIR``,
    or an earlier call) is kept and returned. The minimum compile time for an entry is lowered from 1 s to 0 so that
    a solve's many small programs (objective, derivatives, re-simulation) are cached too: on a second run they are
    what remains once the large ones are read back.

    ``requested``: a folder (``~`` expanded), an off word (see the module docstring), or None (the environment's
    choice or the default). Returns the folder in use, or None when the cache is off.
    """
    import jax

    current = jax.config.jax_compilation_cache_dir
    if current:
        if programs.program_folder() is None:
            programs.set_program_folder(os.path.join(current, "programs"))
        return current
    path = compilation_cache_dir(requested)
    if path is None:
        return None
    os.makedirs(path, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    programs.set_program_folder(os.path.join(path, "programs"))
    return path
