"""myriad.compiler: YAML specs → sympy → checked IR → generated JAX modules (no JAX is imported here)."""

from .build import build as build
from .build import compile_file as compile_file
from .build import compile_spec as compile_spec
from .errors import CodegenError as CodegenError
from .errors import SpecError as SpecError
from .errors import SpecErrors as SpecErrors
from .schema import SCHEMA_VERSION as SCHEMA_VERSION
from .schema import SUPPORTED_SCHEMAS as SUPPORTED_SCHEMAS

__all__ = ["build", "compile_file", "compile_spec", "CodegenError", "SpecError", "SpecErrors", "SCHEMA_VERSION",
           "SUPPORTED_SCHEMAS"]
