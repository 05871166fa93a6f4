"""myriad.compiler: YAML specs → sympy → checked IR → generated JAX modules (no JAX is imported here)."""

from .build import build as build, compile_file as compile_file, compile_spec as compile_spec
from .errors import CodegenError as CodegenError, SpecError as SpecError, SpecErrors as SpecErrors
from .schema import SCHEMA_VERSION as SCHEMA_VERSION

__all__ = ["build", "compile_file", "compile_spec", "CodegenError", "SpecError", "SpecErrors", "SCHEMA_VERSION"]
