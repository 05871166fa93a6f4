"""Test-wide settings: float64 everywhere and strict dtype promotion, so silent float32 or int/float mixing fails."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
