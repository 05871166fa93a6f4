"""The distributions of a system's uncertain parameters (schema 3's ``uncertain:``): draws from a key, in JAX, and
their exact moments (what the tests compare draws against). Parametrisations and ``widen``: README.md in this folder.

    theta = draw(system, key)              # (n_uncertain,): one draw of every uncertain parameter, vmap-able
    thetas = sample(system, key, 1000)     # (1000, n_uncertain)
    params = with_values(system, params, theta)   # the parameter dict with the drawn values in place
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..system import System

__all__ = ["KINDS", "uncertain_spec", "draw", "sample", "with_values", "mean", "std", "fourth_central_moment",
           "centre", "support"]

# The number of arguments of each kind ("choice": one or more values).
KINDS = {"uniform": 2, "normal": 2, "lognormal": 2, "choice": None}


def uncertain_spec(system: System) -> tuple[tuple[str, ...], tuple[str, ...], tuple[tuple[float, ...], ...]]:
    """``(names, kinds, args)`` of the system's uncertain parameters (schema 3's class attributes; empty before
    schema 3 or for a spec without ``uncertain:``), checked: a malformed set is a ``ValueError`` naming it."""
    names = tuple(getattr(system, "uncertain_params", ()))
    kinds = tuple(getattr(system, "uncertain_kinds", ()))
    args = tuple(tuple(float(v) for v in a) for a in getattr(system, "uncertain_args", ()))
    if not len(names) == len(kinds) == len(args):
        raise ValueError(f"{system.name}: uncertain_params, uncertain_kinds and uncertain_args differ in length "
                         f"({len(names)}, {len(kinds)}, {len(args)})")
    for name, kind, a in zip(names, kinds, args):
        if name not in system.param_names:
            raise ValueError(f"{system.name}: uncertain parameter {name!r} is not a parameter "
                             f"({', '.join(system.param_names)})")
        _check(f"{system.name}: parameter {name!r}", kind, a)
    return names, kinds, args


def _check(where: str, kind: str, args: tuple[float, ...]) -> None:
    if kind not in KINDS:
        raise ValueError(f"{where}: unknown distribution {kind!r}; one of {', '.join(KINDS)}")
    n = KINDS[kind]
    if (n is not None and len(args) != n) or not args or not all(math.isfinite(v) for v in args):
        raise ValueError(f"{where}: {kind} takes {n or 'one or more'} finite numbers, got {list(args)}")
    if kind == "uniform" and not args[0] < args[1]:
        raise ValueError(f"{where}: uniform [lo, hi] needs lo < hi, got {list(args)}")
    if kind in ("normal", "lognormal") and not args[1] > 0:
        raise ValueError(f"{where}: {kind} [{'mean, std' if kind == 'normal' else 'mu, sigma'}] needs a positive "
                         f"spread, got {list(args)}")


def _check_widen(widen: Any) -> None:
    if isinstance(widen, (int, float)) and not (0 <= widen < math.inf):
        raise ValueError(f"widen must be a finite number >= 0, got {widen}")


def _one(kind: str, args: tuple[float, ...], key: Any, shape: tuple[int, ...], widen: Any, dtype: Any) -> Any:
    """``shape`` draws of one parameter: its distribution with the spread about its centre scaled by ``widen``."""
    if kind == "uniform":
        lo, hi = args
        c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        return c + widen * half * jax.random.uniform(key, shape, dtype, -1.0, 1.0)
    if kind == "normal":
        return args[0] + widen * args[1] * jax.random.normal(key, shape, dtype)
    if kind == "lognormal":
        return jnp.exp(args[0] + widen * args[1] * jax.random.normal(key, shape, dtype))
    values = np.asarray(args, np.float64)  # choice: equally likely values, spread about their mean
    c = float(np.mean(values))
    picked = jnp.asarray(values, dtype)[jax.random.randint(key, shape, 0, len(values))]
    # The declared values themselves at widen 1: c + (v - c) can be one rounding step off v (0.15000000000000002).
    return jnp.where(jnp.asarray(widen) == 1.0, picked, c + widen * (picked - c))


def sample(system: System, key: Any, n: int, widen: Any = 1.0, dtype: Any = None) -> Any:
    """(n, n_uncertain) draws of the uncertain parameters (columns in ``uncertain_params``' order); row i is
    ``draw(system, jax.random.split(key, n)[i], widen)``. Pure JAX: ``jit``/``vmap`` over ``key`` (and ``widen``,
    an array there)."""
    return jax.vmap(lambda k: draw(system, k, widen, dtype))(jax.random.split(key, n))


def draw(system: System, key: Any, widen: Any = 1.0, dtype: Any = None) -> Any:
    """One draw of every uncertain parameter, shape (n_uncertain,), each from its own stream of ``key``.

    Args:
        widen: >= 0, the factor on each distribution's spread about its centre (README.md: ``widen``): 1 is the
            declared distribution, 0 the centre itself.
        dtype: default float64 under ``jax_enable_x64`` (else float32).
    """
    names, kinds, args = uncertain_spec(system)
    _check_widen(widen)
    dtype = jax.dtypes.canonicalize_dtype(np.float64) if dtype is None else dtype
    if not names:
        return jnp.zeros((0,), dtype)
    keys = jax.random.split(key, len(names))
    return jnp.stack([_one(k, a, keys[i], (), widen, dtype) for i, (k, a) in enumerate(zip(kinds, args))])


def with_values(system: System, params: dict, theta: Any) -> dict:
    """The parameter dict ``params`` with the uncertain parameters set to ``theta`` (n_uncertain,)."""
    names = uncertain_spec(system)[0]
    if not isinstance(params, dict):
        raise ValueError(f"{system.name}: drawing uncertain parameters needs the parameters as a dict of named "
                         f"values, got {type(params).__name__}")
    out = dict(params)
    for i, name in enumerate(names):
        out[name] = jnp.asarray(theta[i], jnp.result_type(params[name]))
    return out


# ---- exact moments of the widened distributions (NumPy, float64) --------------------------------------------------
def centre(kind: str, args: tuple[float, ...]) -> float:
    """What ``widen`` scales about: the midpoint (uniform), the mean (normal), the median e^mu (lognormal, in log
    space about mu) or the values' mean (choice)."""
    _check(kind, kind, tuple(args))
    if kind == "uniform":
        return 0.5 * (args[0] + args[1])
    if kind == "lognormal":
        return math.exp(args[0])
    return float(args[0] if kind == "normal" else np.mean(args))


def mean(kind: str, args: tuple[float, ...], widen: float = 1.0) -> float:
    """E[theta] of the distribution widened by ``widen``."""
    if kind == "lognormal":
        s = widen * args[1]
        return math.exp(args[0] + 0.5 * s * s)
    return centre(kind, args)


def std(kind: str, args: tuple[float, ...], widen: float = 1.0) -> float:
    """The standard deviation of the distribution widened by ``widen``."""
    _check(kind, kind, tuple(args))
    if kind == "uniform":
        return widen * (args[1] - args[0]) / math.sqrt(12.0)
    if kind == "normal":
        return widen * args[1]
    if kind == "lognormal":
        s2 = (widen * args[1]) ** 2
        return math.sqrt(math.expm1(s2) * math.exp(2.0 * args[0] + s2))
    return widen * float(np.std(np.asarray(args, np.float64)))


def fourth_central_moment(kind: str, args: tuple[float, ...], widen: float = 1.0) -> float:
    """E[(theta - E theta)^4]: the variance of a sample variance is (mu4 - sigma^4) / n (the tests' errors)."""
    sd = std(kind, args, widen)
    if kind == "uniform":
        return 1.8 * sd ** 4  # kurtosis 9/5
    if kind == "normal":
        return 3.0 * sd ** 4
    if kind == "lognormal":
        s2 = (widen * args[1]) ** 2
        w = math.exp(s2)
        return sd ** 4 * (w ** 4 + 2 * w ** 3 + 3 * w ** 2 - 3)  # excess kurtosis w^4 + 2w^3 + 3w^2 - 6
    v = np.asarray(args, np.float64)
    return float(np.mean((widen * (v - v.mean())) ** 4))


def support(kind: str, args: tuple[float, ...], widen: float = 1.0) -> tuple[float, float]:
    """The smallest interval holding every draw of the widened distribution (infinite sides for normal; (0, inf)
    for lognormal)."""
    _check(kind, kind, tuple(args))
    if kind == "normal":
        return -math.inf, math.inf
    if kind == "lognormal":
        return 0.0, math.inf
    c = centre(kind, args)
    lo, hi = (args[0], args[1]) if kind == "uniform" else (min(args), max(args))
    if widen == 1.0:
        return lo, hi
    return c + widen * (lo - c), c + widen * (hi - c)
