"""The scenarios of a robust plan (schema 3's ``scenarios:`` and ``robust:``): parameter sets stacked on one
leading axis, ready for ``jax.vmap`` (issue 30 item 2's scenario problem is one vmapped axis).

    values = scenario_values(system)        # (S, n_uncertain): the explicit scenarios, else robust_samples draws
    params = scenario_params(system)        # {name: (S,)} for every parameter (the others at their values)
    data = scenario_data(system)            # ProblemData with that batch axis (x0 broadcast)
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from ..data import ProblemData, batch_data
from ..system import System
from .distributions import sample, uncertain_spec

__all__ = ["scenario_values", "scenario_params", "scenario_data"]


def scenario_values(system: System) -> np.ndarray:
    """(S, n_uncertain) float64: the spec's explicit ``scenarios`` in their order, else ``robust_samples`` draws
    of the declared distributions from ``jax.random.PRNGKey(robust_seed)`` (:func:`.distributions.sample`, so
    the same seed gives the same scenarios on every machine with the same JAX)."""
    names = uncertain_spec(system)[0]
    rows = tuple(getattr(system, "scenarios", ()))
    if rows:
        values = np.asarray(rows, np.float64)
        if values.ndim != 2 or values.shape[1] != len(names):
            raise ValueError(f"{system.name}: each scenario needs one value per uncertain parameter "
                             f"({', '.join(names) or 'none'}), got shape {values.shape}")
        return values
    if not names:
        raise ValueError(f"{system.name}: no scenarios: the spec declares neither scenarios nor uncertain parameters")
    n = int(getattr(system, "robust_samples", 16))
    if n < 1:
        raise ValueError(f"{system.name}: robust_samples must be at least 1, got {n}")
    with jax.enable_x64(True):  # the scenarios do not depend on the caller's precision
        draws = sample(system, jax.random.PRNGKey(int(getattr(system, "robust_seed", 0))), n)
        return np.asarray(draws, np.float64)


def scenario_params(system: System, values: Any = None) -> dict[str, np.ndarray]:
    """{name: (S,)} for every parameter: the uncertain ones from ``values`` (default :func:`scenario_values`), the
    others repeated at the spec's value."""
    values = scenario_values(system) if values is None else np.asarray(values, np.float64)
    names = uncertain_spec(system)[0]
    n = values.shape[0]
    out = {k: np.full(n, v, np.float64) for k, v in zip(system.param_names, system.param_values)}
    for i, name in enumerate(names):
        out[name] = values[:, i].copy()
    return out


def scenario_data(system: System, values: Any = None) -> ProblemData:
    """The scenarios as a batch of :class:`~myriad.runtime.data.ProblemData` (leading axis S, x0 broadcast)."""
    params = scenario_params(system, values)
    n = next(iter(params.values())).shape[0] if params else 0
    return batch_data(system, params, np.broadcast_to(np.asarray(system.x0, np.float64), (n, system.n_states)))
