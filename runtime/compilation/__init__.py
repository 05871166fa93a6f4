"""Compilation infrastructure: what every solver, transcription and simulation compiles through, naming none of them:
functions compiled ahead of time (:mod:`.compiled`), the traced programs kept on disk (:mod:`.programs`) and JAX's
persistent compilation cache, which decides where they live (:mod:`.jax_cache`); and the one BLAS thread the compiled
programs' LAPACK calls run on during a solve (:mod:`.blas`).

Layering: this package imports only JAX, NumPy (SciPy and threadpoolctl in :mod:`.blas`) and
:mod:`myriad.runtime.atomic`; solvers, transcriptions and core types import it, never the reverse
(``tests/runtime/test_layering.py``).
"""

from . import jax_cache as jax_cache
from . import programs as programs
from .compiled import CompiledFunction as CompiledFunction
from .compiled import compile_many as compile_many
from .compiled import program_key as program_key

__all__ = ["CompiledFunction", "compile_many", "jax_cache", "program_key", "programs"]
