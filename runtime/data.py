"""Problem data: what may change between solves without recompiling (the parameters and the initial state).

Every NLP function, rollout and pure solve takes a :class:`ProblemData`. Its ``params`` may be any pytree: the
spec's ``dict[str, Array]`` by default, or a learned model's nested parameters (a network inside); only the
leaves' shapes are static, so new values reuse compiled code and a batch of problems is one ``jax.vmap``.

User input is checked here, before anything compiles: an ``x0`` or parameter of the wrong shape, or a parameter
name the system does not have, is a ``ValueError`` (``KeyError`` for a name) naming the argument, the expected
shape and the state or parameter names, not a broadcasting error from deep inside a traced program.
"""

from __future__ import annotations

import difflib
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compilation.programs import register_namedtuple
from .system import System

__all__ = ["ProblemData", "default_data", "batch_data", "check_structural_params", "require_float64"]


@register_namedtuple  # the argument of every stored program
class ProblemData(NamedTuple):
    """The data of one problem (a pytree; under ``vmap`` every leaf gains a leading batch axis).

    Attributes:
        params: the parameters, any pytree (a ``dict[str, Array]`` for a compiled system).
        x0: the initial state, shape (n_states,).
    """

    params: Any
    x0: Any


def _dtype():
    # Every leaf gets the same concrete (not weakly typed) float dtype, whatever the caller passed: a Python float
    # and a float64 array trace differently, and a jitted NLP function would silently recompile for new data.
    return jax.dtypes.canonicalize_dtype(np.float64)


def require_float64(entry: str) -> None:
    """Refuse to optimise in float32 (JAX's default) with the one-line fix, before any work.

    A trajectory optimisation in float32 does not fail loudly: its KKT residuals stall near 1e-4, so the solver
    stops at its iteration limit or calls a feasible problem infeasible. The library does not flip the global
    ``jax_enable_x64`` flag itself: that would change the precision of the user's other JAX code behind their back
    (diffrax and optimistix likewise compute in the dtype they are given)."""
    if jax.dtypes.canonicalize_dtype(np.float64) != np.float64:
        raise RuntimeError(
            f"{entry} needs float64, but JAX is in float32 (its default), where trajectory optimisation stops at "
            f"the iteration limit or reports feasible problems infeasible; enable float64 once, right after "
            f"`import jax`: jax.config.update(\"jax_enable_x64\", True) (or set JAX_ENABLE_X64=1)")


def default_data(system: System, params: dict | None = None, x0: Any = None) -> ProblemData:
    """The system's problem data, with some parameters and/or the initial state replaced.

    Args:
        params: parameter values; missing names take the spec's defaults.
        x0: the initial state; defaults to ``system.x0``.

    Raises:
        KeyError: a parameter the system does not have (with the closest names).
        ValueError: an ``x0`` or parameter value of the wrong shape, or a new value for a structural parameter (see
            :func:`check_structural_params`).
    """
    dtype = _dtype()
    # Host (NumPy) leaves where nothing is traced: a compiled program takes them as they are, while making device
    # arrays of them one at a time (jnp.asarray, jax.device_put) cost ~70 us a leaf, a tenth of a small warm solve.
    p = _default_params(system, dtype)
    new = {k: _leaves(v, dtype) if k in p else v for k, v in (params or {}).items()}  # unknown names: KeyError
    x0 = _leaf(system.x0 if x0 is None else x0, dtype)
    _check(system, new, p, x0, batch=())
    p.update(new)
    return ProblemData(params=p, x0=x0)


def batch_data(system: System, params: dict | None = None, x0: Any = None) -> ProblemData:
    """A batch of problem data with a leading batch axis on every leaf.

    Args:
        params: arrays of shape (B,) per parameter; names not given keep the spec's value.
        x0: (B, n_states) initial states, or None for the spec's.

    Raises:
        ValueError: no batch axis, or batch sizes that differ between the arguments.
    """
    params = {k: _leaves(v, _dtype()) for k, v in (params or {}).items()}
    sizes = {int(np.shape(a)[0]) if np.ndim(a) else -1 for a in jax.tree.leaves(params)}
    if x0 is not None:
        sizes.add(int(np.shape(x0)[0]) if np.ndim(x0) > 1 else -1)
    if -1 in sizes:
        raise ValueError("a batch needs a leading batch axis on every parameter given and a (B, n_states) x0")
    if len(sizes) != 1:
        raise ValueError(f"a batch needs one batch size across params and x0, got {sorted(sizes) or 'none'}")
    (batch,) = sizes
    base = default_data(system)
    _check(system, params, base.params, x0, batch=(batch,))
    p = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch, *jnp.shape(a))), base.params)
    p.update(params)
    xs = jnp.broadcast_to(base.x0, (batch, system.n_states)) if x0 is None else jnp.asarray(x0, _dtype())
    return ProblemData(params=p, x0=xs)


def _default_params(system: System, dtype) -> Any:
    """The system's own parameters: the spec's values as host arrays, or what a subclass that overrides
    ``default_params`` (a learned system's nested model parameters) gives."""
    if type(system).default_params is System.default_params:
        return {k: np.asarray(v, dtype=dtype) for k, v in zip(system.param_names, system.param_values)}
    return system.default_params(dtype)


def _leaves(value: Any, dtype) -> Any:
    """A parameter value (a number, an array or a list of numbers, or a pytree such as a network) with every leaf a
    ``dtype`` array. A list or tuple is one array, as ``jnp.asarray`` reads it, not a pytree of scalars."""
    if isinstance(value, (list, tuple)):
        return _leaf(value, dtype)
    return jax.tree.map(lambda a: _leaf(a, dtype), value)


def _leaf(value: Any, dtype) -> Any:
    """``value`` as a ``dtype`` array: a JAX array (or tracer) stays one, anything else becomes a NumPy array."""
    if isinstance(value, jax.Array):
        return value if value.dtype == dtype and not value.weak_type else jnp.asarray(value, dtype=dtype)
    return np.asarray(value, dtype=dtype)


def _check(system: System, given: dict, known: dict, x0: Any, batch: tuple) -> None:
    """Parameter names (``KeyError``), then their shapes (after a leading batch axis in a batch), their structural
    values and the shape of ``x0`` unless None (``ValueError``)."""
    unknown = sorted(set(given) - set(known))
    if unknown:
        # cutoff 0.5: parameter names are short (m1, m2), where one wrong character is already half the name
        close = {k: difflib.get_close_matches(k, list(known), 1, 0.5) for k in unknown}
        hints = [f"{k!r} (did you mean {close[k][0]!r}?)" if close[k] else repr(k) for k in unknown]
        raise KeyError(f"{system.name}: unknown parameter{'s' if len(unknown) > 1 else ''} {', '.join(hints)}; "
                       f"its parameters are {', '.join(known) or 'none'}")
    for name, value in given.items():
        want = jax.tree.map(lambda a: (*batch, *np.shape(a)), known[name])
        got = jax.tree.map(np.shape, value)
        if want != got:
            raise ValueError(f"params[{name!r}] has shape {got}, expected {want}"
                             f"{' (a leading batch axis, then the value)' if batch else ''} for {system.name}'s "
                             f"parameter `{name}`")
    check_structural_params(system, given)
    expected = (*batch, system.n_states)
    if x0 is not None and tuple(np.shape(x0)) != expected:
        names = ", ".join(system.state_names)
        got = f"{np.size(x0)} value{'s' if np.size(x0) != 1 else ''}" if np.ndim(x0) <= 1 else f"shape {np.shape(x0)}"
        raise ValueError(f"x0 has {got}, expected shape {expected}: {system.name} has {system.n_states} "
                         f"state{'s' if system.n_states != 1 else ''} ({names})")


def check_structural_params(system: System, params: dict) -> None:
    """Refuse a new value for a parameter that the spec's initial values, bounds, final values or horizon use.

    Those fields are compiled as numbers at the spec's parameter values, so solving with another value would
    silently keep, e.g., Predator-Prey's required z(T) = B at 5 while ``B`` says 4. Traced values (inside a
    transformation) cannot be compared and pass.
    """
    for name in system.structural_params:
        if name not in params or isinstance(params[name], jax.core.Tracer):
            continue
        default = system.param_values[system.param_names.index(name)]
        value = np.asarray(params[name], dtype=np.float64)
        if not np.all(value == default):
            raise ValueError(
                f"{system.name}: parameter `{name}` = {value.ravel()[0] if value.size == 1 else value} differs from "
                f"the spec's {default:g}, but the spec's initial values, bounds, final values or horizon use `{name}`, "
                f"and those are compiled as numbers at {name} = {default:g}; they would not follow. Copy the spec "
                f"with the new value of `{name}` and load that file instead"
            )
