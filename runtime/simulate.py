"""Simulate a control trajectory: states, cost and final-state defect on a uniform node grid."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compilation import CompiledFunction, program_key, programs
from .compilation.caches import program_cache
from .integrators import AbstractIntegrator, Heun, rollout_with_cost
from .system import System

__all__ = ["Simulation", "simulate"]


@programs.register_namedtuple  # the output of a stored simulation program
class Simulation(NamedTuple):
    """The outcome of :func:`simulate` (a pytree of arrays).

    Attributes:
        times: (N + 1,) the nodes t_k = k T / N.
        states: (N + 1, n) the states at the nodes.
        cost: J = phi(x(T), T) + int_0^T L dt, minimisation form.
        running_cost: int_0^T L dt, integrated as an extra state by the same integrator.
        terminal_cost: phi(x(T), T).
        defect: (n,) x(T) - x_final for every state with a required final value, NaN where x_i(T) is free (so the
            vector lines up with ``system.state_names``; take ``jnp.nanmax(jnp.abs(defect))`` for the worst miss, or
            :attr:`max_defect`).
    """

    times: Any
    states: Any
    cost: Any
    running_cost: Any
    terminal_cost: Any
    defect: Any

    @property
    def max_defect(self) -> Any:
        """max_i |x_i(T) - x_final,i| over the required final values; 0 when there are none."""
        return jnp.max(jnp.where(jnp.isnan(self.defect), 0.0, jnp.abs(self.defect)), initial=0.0)


def simulate(
    system: System,
    controls: Any,
    params: dict | None = None,
    x0: Any = None,
    integrator: AbstractIntegrator = Heun(),
) -> Simulation:
    """Integrate ``system`` under a control trajectory given at N + 1 uniformly spaced nodes over [0, T].

    The control is linearly interpolated between nodes and the running cost is integrated as an extra state by
    the same ``integrator``. With the default Heun on the 100-step grid this reproduces the discretised cost and
    defect of the published setting; with :class:`~myriad.runtime.integrators.DormandPrince` it is the
    "re-simulated" evaluation that ``solve()`` and the bench report separately. The two must never be mixed.

    Args:
        controls: (N + 1, m) control values at t_k = k T / N (a 1-D array is accepted when m = 1).
        params: parameter values (default: the spec's); a partial dict overrides only the names it has.
        x0: initial state (default: the spec's).
        integrator: the one-step method.
    """
    controls = jnp.asarray(controls)
    if not jnp.issubdtype(controls.dtype, jnp.floating):
        controls = controls.astype(float)
    if controls.ndim == 1 and system.n_controls == 1:
        controls = controls[:, None]
    if controls.ndim != 2 or controls.shape[1] != system.n_controls or controls.shape[0] < 2:
        raise ValueError(
            f"{system.name}: controls must have shape (N + 1, {system.n_controls}) with N >= 1, got {controls.shape}"
        )
    p = system.default_params(controls.dtype)
    p.update(params or {})
    x0 = jnp.asarray(system.x0 if x0 is None else x0, dtype=controls.dtype)
    stored = _stored(system, integrator)
    args = (controls, p, x0)
    if stored is None or any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(args)):
        return _simulate(system, integrator, controls, p, x0)
    # Concrete inputs with the program store on (compilation.programs): one program per system, integrator and
    # shapes, read back from disk by a later process instead of traced again.
    # Arrays keep their dtype; a Python number takes the controls' (what a weakly typed scalar becomes in _simulate).
    args = jax.tree.map(lambda a: jax.device_put(np.asarray(a) if hasattr(a, "dtype")
                                                 else np.asarray(a, dtype=controls.dtype)), args)
    stored.compile(*args)
    return stored(*args)


@program_cache(maxsize=256)
def _stored_fn(system: System, integrator: AbstractIntegrator, key: str):
    return CompiledFunction(lambda controls, p, x0: _simulate(system, integrator, controls, p, x0), key)


def _stored(system: System, integrator: AbstractIntegrator):
    """The simulation as a stored program, or None (store off, or the system or integrator has no key)."""
    if programs.program_folder() is None:
        return None
    key = program_key(programs.system_key(system), "simulate", programs.describe(integrator))
    return None if key is None else _stored_fn(system, integrator, key)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _simulate(system: System, integrator: AbstractIntegrator, controls, params, x0) -> Simulation:
    N = controls.shape[0] - 1
    T = float(system.horizon)
    states, running = rollout_with_cost(
        integrator,
        lambda x, u, t: system.dynamics(x, u, t, params),
        lambda x, u, t: system.running_cost(x, u, t, params),
        x0,
        0.0,
        T / N,
        controls,
    )
    terminal = jnp.asarray(system.terminal_cost(states[-1], T, params), dtype=states.dtype)
    return Simulation(
        times=jnp.asarray(np.linspace(0.0, T, N + 1)),
        states=states,
        cost=running[-1] + terminal,
        running_cost=running[-1],
        terminal_cost=terminal,
        defect=states[-1] - jnp.asarray(system.final_values),
    )
