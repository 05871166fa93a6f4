"""The model interface: a learnable vector field that stands in for a system's dynamics.

A model ``M`` with parameters ``theta`` replaces the true dynamics ``f(x, u, t, p)`` by
``M.vector_field(x, u, t, theta, p)`` and keeps everything else of the true system (horizon, x0, bounds, required
final values, costs at the spec's parameters ``p``). ``theta`` is a pytree of arrays; the model object is a frozen,
hashable dataclass holding only configuration, so it can be a static argument of ``jax.jit``.

A fit differentiates with respect to the trainable part only (``model.partition``): ``optax.masked(opt, mask)`` alone
is *not* enough, it passes the raw gradient of a masked-out leaf through as its update, so ``apply_updates`` would
still move the normalisation constants.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
from typing import TYPE_CHECKING, Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ...system import System

if TYPE_CHECKING:  # pragma: no cover
    from .learned_system import LearnedSystem

__all__ = ["AbstractModel", "float_dtype"]


def float_dtype() -> Any:
    """The runtime's float dtype: float64 (float32 only if JAX's x64 mode is off), as in ``runtime/data.py``."""
    return jax.dtypes.canonicalize_dtype(np.float64)


@dataclasses.dataclass(frozen=True)
class AbstractModel(abc.ABC):
    """A learnable model of the true ``system``'s dynamics (concrete models: frozen, hashable dataclasses).

    Class attributes:
        label: the model's one name: its key in ``MODELS``, the configurations' and commands' ``model``.
        spec_form: True when the vector field *is* the spec's dynamics at some parameters (see
            :meth:`spec_form_params`), so the compiler's derivative artefacts (Jacobians, costates, u*) apply.
    """

    system: System

    label: ClassVar[str]
    spec_form: ClassVar[bool] = False
    # The class of the systems a model becomes (``as_system``): LearnedSystem, which registers itself here when its
    # module is imported (the package's __init__ does), so this module does not import the one that subclasses it.
    system_class: ClassVar[type]

    # Per-model defaults of the learners (PyBaMM's ``default_*`` idea): a configuration field left at None takes its
    # model's, so a new model brings its own and no learner names a model. Measured in docs/notes/node-training.md
    # and docs/notes/e2e-node.md.
    default_method: ClassVar[str] = "adam"  # system identification: how to fit (least squares or Adam)
    default_rounds: ClassVar[int] = 1  # system identification: datasets in sequence
    default_polish: ClassVar[bool] = False  # system identification: an L-BFGS polish after each Adam fit
    default_reaim: ClassVar[int] = 0  # re-aims of the judged plan from observed true runs
    default_unroll: ClassVar[int] = 10  # end-to-end learning: planner steps per iteration
    default_iterations: ClassVar[int] = 600  # end-to-end learning: outer iterations (optimiser updates)

    def __post_init__(self):
        if not isinstance(self.system, System):
            raise TypeError(f"{type(self).__name__}: `system` must be a myriad System, "
                            f"got {type(self.system).__name__}")
        if isinstance(self.system, AbstractModel.system_class):
            raise TypeError(f"{type(self).__name__}: model the true system, not a LearnedSystem ({self.system!r})")

    # ---- the contract ----------------------------------------------------------------------------------------

    @abc.abstractmethod
    def init_params(self, key: Any = None, data: Any = None) -> Any:
        """Starting parameters ``theta`` (float64 arrays) from a ``jax.random`` key and, for data-dependent
        initialisation (normalisation), a ``Trajectories`` or None."""

    @abc.abstractmethod
    def vector_field(self, x: Any, u: Any, t: Any, theta: Any, spec_params: dict) -> Any:
        """dx/dt = f_theta(x, u, t), shape (n_states,); ``spec_params`` is the spec's parameter dict."""

    def trainable(self, theta: Any) -> Any:
        """A pytree of bools with the structure of ``theta``: True where an optimiser may change the leaf."""
        return jax.tree.map(lambda _: True, theta)

    def spec_form_params(self, theta: Any, spec_params: dict) -> dict:
        """The spec parameters at which ``vector_field`` equals ``system.dynamics`` (only when ``spec_form``)."""
        raise NotImplementedError(f"{type(self).__name__}: the vector field is not the spec's dynamics")

    # ---- written once ----------------------------------------------------------------------------------------

    def as_system(self, theta: Any, aim: Any = None) -> "LearnedSystem":
        """The model with parameters ``theta`` as a :class:`LearnedSystem` (``solve`` takes it unchanged); ``aim``
        shifts the planner's final values (see :class:`LearnedSystem`)."""
        return AbstractModel.system_class(self, theta, aim)

    def n_parameters(self, theta: Any) -> int:
        """The number of trainable scalars in ``theta``."""
        mask = self.trainable(theta)
        return int(sum(int(np.size(a)) for a, m in zip(jax.tree.leaves(theta), jax.tree.leaves(mask)) if m))

    def partition(self, theta: Any) -> tuple[Any, Any]:
        """``(trainable, frozen)``: two pytrees shaped like ``theta``, each with None where the other has a leaf."""
        return eqx.partition(theta, self.trainable(theta))

    @staticmethod
    def combine(trainable: Any, frozen: Any) -> Any:
        """The inverse of :meth:`partition`."""
        return eqx.combine(trainable, frozen)

    def check_params(self, theta: Any) -> None:
        """Raise ValueError unless ``theta`` has the structure and leaf shapes of :meth:`init_params`'s."""
        template = _template(self)
        got, want = jax.tree.structure(theta), jax.tree.structure(template)
        if got != want:
            raise ValueError(f"{self.label} model of {self.system.name}: parameters with structure {got}, "
                             f"expected {want} (that of init_params)")
        for (path, a), b in zip(jax.tree_util.tree_flatten_with_path(theta)[0], jax.tree.leaves(template)):
            if tuple(np.shape(a)) != tuple(b.shape):
                raise ValueError(f"{self.label} model of {self.system.name}: parameter "
                                 f"theta{jax.tree_util.keystr(path)} has shape {tuple(np.shape(a))}, "
                                 f"expected {tuple(b.shape)}")


@functools.lru_cache(maxsize=64)
def _template(model: AbstractModel) -> Any:
    """Shapes and dtypes of ``model.init_params`` (evaluated abstractly, once per model configuration)."""
    return jax.eval_shape(lambda key: model.init_params(key, None), jax.random.PRNGKey(0))


def as_float(theta: Any) -> Any:
    """Every leaf as an array of the runtime's float dtype."""
    dtype = float_dtype()
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=dtype), theta)
