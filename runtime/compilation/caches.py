"""The runtime's caches of compiled programs, and one call that empties them all: :func:`clear_caches`.

Why a process needs it: XLA keeps each CPU program's machine code in about three memory mappings while the program is
alive, and Linux allows a process 65,530 mappings (``vm.max_map_count``). The runtime keeps what it compiled (per
system, transcription and NLP) so that the next solve of the same problem runs at once; a process that goes through
hundreds of different problems (a test session, a notebook over every spec, a sweep in one process) fills the table,
and the allocation that fails then crashes XLA (a segfault, not an error). Clearing drops the programs; the next
solve of a problem compiles it again (or reads it from the persistent compilation cache).

A cache of anything that holds compiled programs (an NLP, a jitted function, a :class:`CompiledFunction`) is made with
:func:`program_cache`, or registers how to empty itself with :func:`on_clear`; ``tests/conftest.py`` clears after
each test file.
"""

from __future__ import annotations

import functools
import gc
from collections.abc import Callable
from typing import TypeVar

import jax

F = TypeVar("F", bound=Callable)

_CLEARERS: list[Callable[[], None]] = []


def on_clear(clear: Callable[[], None]) -> Callable[[], None]:
    """Register ``clear`` (called with no arguments) to run at every :func:`clear_caches`."""
    _CLEARERS.append(clear)
    return clear


def program_cache(maxsize: int | None = 256) -> Callable[[F], F]:
    """``functools.lru_cache(maxsize)`` whose entries :func:`clear_caches` drops."""

    def decorate(fn: F) -> F:
        cached = functools.lru_cache(maxsize=maxsize)(fn)
        on_clear(cached.cache_clear)
        return cached  # type: ignore[return-value]

    return decorate


def clear_caches() -> None:
    """Drop every compiled program the runtime and JAX hold in their caches, and free their memory now.

    Objects the caller still holds (a solver's compiled step kept in a variable, a jitted function) keep theirs.
    """
    for clear in _CLEARERS:
        clear()
    jax.clear_caches()
    gc.collect()
