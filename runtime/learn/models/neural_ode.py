"""The Neural ODE model: a multilayer perceptron as the vector field, on normalised inputs and outputs.

With per-channel normalisation constants (means ``m`` and standard deviations ``s``)

    x_hat = (x - m_x) / s_x,    u_hat = (u - m_u) / s_u,    tau = t / T  (only with ``time_input``),
    f_theta(x, u, t) = m_dx + s_dx * MLP_theta([x_hat, u_hat(, tau)]),

where ``MLP`` has the hidden widths ``hidden``, the activation ``activation`` after every hidden layer and a linear
output layer of width n_states. The parameters are

    theta = {"net": <tuple of equinox Linear layers: arrays only>,
             "norm": {"x_mean", "x_std", "u_mean", "u_std", "dx_mean", "dx_std"}}.

The normalisation is computed once and not trained: from data, over every node of every trajectory (dx/dt over the
forward differences), each standard deviation floored at ``1e-6 (1 + |mean|)`` so a constant channel does not divide
by zero; without data, the middle and half-width of finite bounds (else 0 and 1), dx/dt with mean 0 and the state's
scale divided by T. The network's static structure is part of the pytree definition of ``theta["net"]``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .base import AbstractModel, float_dtype

__all__ = ["NeuralODE", "ACTIVATIONS", "network_error"]

ACTIVATIONS = {
    "sigmoid": jax.nn.sigmoid,
    "softplus": jax.nn.softplus,
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
}



def network_error(hidden: Any, activation: Any) -> str | None:
    """Why a learner's config cannot make a Neural ODE of these (None if it can), naming the fields ``hidden`` and
    ``activation``: checked when the config is built, before any work, whichever model it learns."""
    widths = tuple(hidden) if isinstance(hidden, (list, tuple)) else None
    if not widths or not all(isinstance(w, (int, np.integer)) and not isinstance(w, bool) and w >= 1 for w in widths):
        return f"hidden must be a list of layer widths >= 1, got {hidden!r}"
    if not isinstance(activation, str) or activation not in ACTIVATIONS:
        return f"activation must be one of {', '.join(ACTIVATIONS)}, got {activation!r}"
    return None


@dataclasses.dataclass(frozen=True)
class NeuralODE(AbstractModel):
    """An MLP vector field ``[x, u(, t / T)] -> dx/dt`` with input and output normalisation.

    Attributes:
        hidden: the hidden layers' widths, positive ints (a list is stored as a tuple); ``()`` is a linear model.
        activation: ``"sigmoid"`` (published), ``"softplus"``, ``"tanh"`` or ``"relu"``.
        time_input: also feed t / T to the network (a non-autonomous model).
    """

    hidden: tuple[int, ...] = (100, 100)
    activation: str = "sigmoid"
    time_input: bool = False

    label: ClassVar[str] = "node"
    # Datasets in sequence, a polish and re-aims are what bring a Neural ODE's plan to the required final values
    # (docs/notes/node-training.md); the published unrolled planner takes 5 steps on one.
    default_rounds: ClassVar[int] = 6
    default_polish: ClassVar[bool] = True
    default_reaim: ClassVar[int] = 6
    default_unroll: ClassVar[int] = 5

    def __post_init__(self):
        super().__post_init__()
        hidden = (self.hidden,) if isinstance(self.hidden, (int, np.integer)) else self.hidden
        try:
            hidden = tuple(hidden)
        except TypeError:
            raise ValueError(f"NeuralODE: `hidden` must be a sequence of positive ints, got {self.hidden!r}") from None
        bad = [w for w in hidden if isinstance(w, bool) or not isinstance(w, (int, np.integer)) or w < 1]
        if bad:
            raise ValueError(f"NeuralODE: hidden widths must be positive ints, got {list(hidden)} (bad: {bad})")
        object.__setattr__(self, "hidden", tuple(int(w) for w in hidden))
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"NeuralODE: unknown activation {self.activation!r}; choose one of {list(ACTIVATIONS)}")
        object.__setattr__(self, "time_input", bool(self.time_input))

    @property
    def n_inputs(self) -> int:
        return self.system.n_states + self.system.n_controls + int(self.time_input)

    # ---- parameters ------------------------------------------------------------------------------------------

    def init_params(self, key: Any = None, data: Any = None) -> dict:
        """Network weights from ``key`` (equinox's default initialisation), normalisation from ``data`` (see the
        module docstring)."""
        if key is None:
            raise ValueError("NeuralODE.init_params needs a jax.random key for the network's weights")
        widths = (self.n_inputs, *self.hidden, self.system.n_states)
        keys = jax.random.split(key, len(widths) - 1)
        dtype = float_dtype()
        layers = tuple(eqx.nn.Linear(a, b, key=k, dtype=dtype) for a, b, k in zip(widths[:-1], widths[1:], keys))
        norm = self._norm_from_bounds() if data is None else self._norm_from_data(data)
        return {"net": eqx.filter(layers, eqx.is_array), "norm": {k: jnp.asarray(v, dtype) for k, v in norm.items()}}

    def trainable(self, theta: dict) -> dict:
        """The network is trained, the normalisation is not."""
        return {"net": jax.tree.map(lambda _: True, theta["net"]), "norm": jax.tree.map(lambda _: False, theta["norm"])}

    # ---- the vector field ------------------------------------------------------------------------------------

    def vector_field(self, x: Any, u: Any, t: Any, theta: dict, spec_params: dict) -> Any:
        """``m_dx + s_dx * MLP([x_hat, u_hat(, t / T)])``, shape (n_states,); ``spec_params`` is unused."""
        del spec_params
        nrm = theta["norm"]
        x = jnp.asarray(x)
        parts = [(x - nrm["x_mean"]) / nrm["x_std"], (jnp.asarray(u, x.dtype) - nrm["u_mean"]) / nrm["u_std"]]
        if self.time_input:
            parts.append(jnp.reshape(jnp.asarray(t, x.dtype), (1,)) / float(self.system.horizon))
        z = jnp.concatenate(parts)
        act = ACTIVATIONS[self.activation]
        layers = theta["net"]
        for layer in layers[:-1]:
            z = act(layer(z))
        return nrm["dx_mean"] + nrm["dx_std"] * layers[-1](z)

    # ---- normalisation ---------------------------------------------------------------------------------------

    def _norm_from_data(self, data: Any) -> dict:
        n, m = self.system.n_states, self.system.n_controls
        xs = np.asarray(data.states, dtype=np.float64)
        us = np.asarray(data.controls, dtype=np.float64)
        if xs.ndim != 3 or xs.shape[2] != n or xs.shape[1] < 2:
            raise ValueError(f"NeuralODE({self.system.name}): data.states must have shape (B, N+1, {n}) with N >= 1, "
                             f"got {xs.shape}")
        if us.shape != xs.shape[:2] + (m,):
            raise ValueError(f"NeuralODE({self.system.name}): data.controls must have shape {xs.shape[:2] + (m,)}, "
                             f"got {us.shape}")
        if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(us))):
            raise ValueError(f"NeuralODE({self.system.name}): the data has non-finite states or controls")
        dt = float(self.system.horizon) / (xs.shape[1] - 1)
        dxs = np.diff(xs, axis=1) / dt
        out = {}
        for name, a in (("x", xs), ("u", us), ("dx", dxs)):
            mean, std = _stats(a.reshape(-1, a.shape[-1]))
            out[f"{name}_mean"], out[f"{name}_std"] = mean, std
        return out

    def _norm_from_bounds(self) -> dict:
        a = self.system.arrays()
        x_mean, x_std = _from_bounds(a["x_lower"], a["x_upper"])
        u_mean, u_std = _from_bounds(a["u_lower"], a["u_upper"])
        return {"x_mean": x_mean, "x_std": x_std, "u_mean": u_mean, "u_std": u_std,
                "dx_mean": np.zeros_like(x_mean), "dx_std": x_std / float(self.system.horizon)}


def _floor(mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    return np.maximum(std, 1e-6 * (1.0 + np.abs(mean)))


def _stats(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column mean and (population, floored) standard deviation of (K, d) samples."""
    mean = a.mean(axis=0)
    return mean, _floor(mean, a.std(axis=0))


def _from_bounds(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    both = np.isfinite(lo) & np.isfinite(hi)
    lo, hi = np.where(both, lo, 0.0), np.where(both, hi, 0.0)
    mean = np.where(both, 0.5 * (lo + hi), 0.0)
    return mean, _floor(mean, np.where(both, 0.5 * (hi - lo), 1.0))
