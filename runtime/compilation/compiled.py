"""Functions compiled ahead of time, once per argument signature, and compiled together (with a key,
:func:`program_key`, a traced program may be kept on disk for later processes: :mod:`.programs`)."""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Hashable

import jax

from . import programs

__all__ = ["CompiledFunction", "compile_many", "program_key"]


def program_key(*parts: str | None) -> str | None:
    """A program's key from its parts (an NLP's or system's key, a role, a configuration); None if any is None."""
    return None if any(p is None for p in parts) else "|".join(parts)


class CompiledFunction:
    """``jax.jit(fn)`` compiled ahead of time once per argument signature: an AOT-compiled executable never
    retraces, so the compile cost is paid, and measured, once per signature, and arguments of another shape fail
    loudly instead of recompiling silently."""

    def __init__(self, fn: Callable, key: str | None = None, **jit_kwargs: Any):
        self._jitted = jax.jit(fn, **jit_kwargs)
        self._executables: dict[Hashable, Any] = {}
        # With a key (what the closure depends on, see myriad.runtime.compilation.programs), the traced program may be
        # kept on disk for later processes; static arguments and donation are not exported, so such a function has none.
        self.key = None if jit_kwargs else key

    def lower(self, *args: Any) -> Any:
        return programs.lower(self._jitted, self.key, args)

    def compile(self, *args: Any) -> float:
        """Compile for the signature of ``args`` unless already done; returns the seconds spent (0 if cached)."""
        key = programs.signature(args)
        if key in self._executables:
            return 0.0
        start = time.perf_counter()
        self._executables[key] = self.lower(*args).compile(compiler_options=programs.compiler_options())
        return time.perf_counter() - start

    def __call__(self, *args: Any) -> Any:
        return self._executables[programs.signature(args)](*args)

    def is_compiled(self, *args: Any) -> bool:
        return programs.signature(args) in self._executables

    def executable(self, *args: Any) -> Callable:
        """The compiled executable for the signature of ``args`` (compile first): skips the lookup per call."""
        return self._executables[programs.signature(args)]


def compile_many(jobs: list[tuple[CompiledFunction, tuple]], meanwhile: Callable[[], Any] | None = None) -> float:
    """Compile several functions at once; returns the seconds spent (0 when all were cached).

    Tracing and lowering hold the GIL, so they run one after another; XLA's compilation releases it, so the lowered
    programs compile in parallel threads (on the 2-core machine the table's compile time drops by about a third).
    List the largest program first: it starts earliest. ``meanwhile`` (called once in any case, its result dropped):
    work of the caller's that needs none of these programs, done in this thread while XLA compiles them (IPOPT's
    import: 0.3 s of a cold solve, issue 31); it is not counted in the seconds returned.
    """
    pending = [(cf, args) for cf, args in jobs if not cf.is_compiled(*args)]
    if not pending:
        if meanwhile is not None:
            meanwhile()
        return 0.0
    start = time.perf_counter()
    lowered = [(cf, programs.signature(args), cf.lower(*args)) for cf, args in pending]
    workers = max(1, min(len(lowered), os.cpu_count() or 1))
    options = programs.compiler_options()
    aside = 0.0
    if workers == 1 and meanwhile is None:
        executables = [low.compile(compiler_options=options) for _, _, low in lowered]
    else:
        with ThreadPoolExecutor(workers) as pool:
            futures = [pool.submit(low.compile, compiler_options=options) for _, _, low in lowered]
            if meanwhile is not None:
                began = time.perf_counter()
                meanwhile()
                aside = time.perf_counter() - began
            executables = [f.result() for f in futures]
    for (cf, key, _), exe in zip(lowered, executables):
        cf._executables[key] = exe
    return time.perf_counter() - start - aside
