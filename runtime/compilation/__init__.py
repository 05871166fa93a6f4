"""Compilation infrastructure: what every solver, transcription and simulation compiles through, naming none of them.

* :mod:`.compiled`: :class:`CompiledFunction` (``jax.jit`` compiled ahead of time, once per argument signature),
  :func:`compile_many` (several at once, XLA in parallel threads) and :func:`program_key`;
* :mod:`.programs`: the traced programs kept on disk (``jax.export``), so a second process skips tracing; types
  that cross a stored program's boundary register themselves with :func:`programs.register_namedtuple`;
* :mod:`.jax_cache`: JAX's persistent compilation cache in a user folder (``$MYRIAD_JAX_CACHE``), which also
  decides where the program store lives.

Layering: this package imports only JAX, NumPy and :mod:`myriad.runtime.atomic`; solvers, transcriptions and core
types import it, never the reverse (``tests/runtime/test_layering.py``).
"""

from . import jax_cache as jax_cache
from . import programs as programs
from .compiled import CompiledFunction as CompiledFunction
from .compiled import compile_many as compile_many
from .compiled import program_key as program_key

__all__ = ["CompiledFunction", "compile_many", "jax_cache", "program_key", "programs"]
