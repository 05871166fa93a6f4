"""Trajectory datasets for the learners: trajectories of a system's *true* dynamics under sampled controls.

On the grid t_k = k T / N, k = 0..N (N = ``Sampling.intervals``), with the spec's ranges r_u = u_max - u_min,
r_x = x_max - x_min (elementwise) and s = spread * r_u:

- controls, ``"random_walk"`` (the published default): u_0 ~ U(u_min, u_max), u_{k+1} = clip(u_k + N(0, s^2));
  ``"uniform"``: u_k ~ U(u_min, u_max) i.i.d. (without the published code's extra factor 0.75);
  ``"around"``: u_k = clip(a_k + N(0, s^2)) for given controls a (N + 1, m) (e.g. a plan, "datasets in sequence");
  optionally (``smooth``) then two passes of the published kernel [24, 35, 39, 35, 24] / 157 (edge-padded);
- start: x(0) = clip(x0 + N(0, diag(sigma^2))) with sigma = x0_std (``x0_relative=False``), or x0_std |x0_i|
  (``x0_relative=True``; x0_std r_x,i where x0_i = 0);
- states: the true dynamics f(x, u, t, p_spec) integrated node to node by ``Sampling.integrator`` (Heun by default,
  the same states as :func:`~myriad.runtime.simulate.simulate`) under the piecewise-linear control;
- observation: y_k = clip(x_k + N(0, (noise r_x)^2)) if noise > 0; with noise = 0 the rollout itself, unclipped.
  With ``noise_scale="spread"``, r_x,i is instead the spread max - min of state i over all the noise-free
  trajectories drawn together: no bounds needed, and noise <= 1 still means noise no wider than what it observes.

One jit-compiled, vmapped program makes all trajectories (train, then validation, then test; trajectory i from row i
of one uniform draw from ``key(seed)``): a seed fixes every bit. A scheme needing a finite bound the system lacks
raises ``ValueError`` naming the state or control and the bound, before any work. Arrays: read-only float64 NumPy.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import operator
import os
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..atomic import atomic_open, atomic_write_text
from ..integrators import INTEGRATORS, AbstractIntegrator, Heun, rollout
from ..loader import load
from ..system import System, UnsupportedFeature

__all__ = ["Sampling", "Trajectories", "Dataset", "check_source", "dataset_id", "make_dataset", "sampling_scales",
           "save_dataset", "load_dataset"]

SCHEMES = ("random_walk", "uniform", "around")
FORMAT, VERSION = "myriad.sysid.dataset", 1  # the name predates the kit; kept, so older files load
_SPLITS = ("train", "validation", "test")
_KERNEL = np.array([24.0, 35.0, 39.0, 35.0, 24.0]) / 157.0  # the published "Gaussian blur", exactly


def _count(v: Any) -> int:  # an integer (NumPy ones too), or -1 for anything else (bools, floats): checks then fail
    return operator.index(v) if hasattr(type(v), "__index__") and not isinstance(v, bool) else -1


@dataclasses.dataclass(frozen=True)
class Sampling:
    """How controls, start states and observation noise are drawn (a hashable, static configuration).

    Attributes:
        controls: "random_walk", "uniform" or "around" (see the module docstring).
        spread: random-walk step std and "around" perturbation std, as a fraction of the control range.
        x0_std: std of the start-state perturbation: absolute, or a fraction of |x0| with ``x0_relative``.
        x0_relative: see ``x0_std``; a state with x0 = 0 then uses a fraction of its range.
        noise: observation-noise std as a fraction of the state range (then clipped to the bounds), in [0, 1]; 0:
            none.
        noise_scale: what ``noise`` is a fraction of: "range" (x_max - x_min, the published unit) or "spread" (each
            state's spread in the noise-free data: the unit for a state without finite bounds).
        intervals: N, the number of grid intervals (N + 1 nodes).
        integrator: the one-step method (``Adaptive()`` allowed: it then integrates each interval adaptively).
        smooth: smooth the controls with the published kernel (two passes).
    """

    controls: str = "random_walk"
    spread: float = 0.05
    x0_std: float = 0.1
    x0_relative: bool = False
    noise: float = 0.0
    noise_scale: str = "range"
    intervals: int = 100
    integrator: AbstractIntegrator = Heun()
    smooth: bool = False

    def __post_init__(self):
        if self.controls not in SCHEMES:
            raise ValueError(f"Sampling: controls must be one of {SCHEMES}, got {self.controls!r}")
        for name in ("spread", "x0_std", "noise"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"Sampling: {name} must be a finite number >= 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.noise > 1 or self.noise_scale not in ("range", "spread"):
            raise ValueError(f"Sampling: noise must be at most 1 (a fraction of the state's {self.noise_scale}) and "
                             f"noise_scale 'range' or 'spread', got {self.noise!r} and {self.noise_scale!r}")
        for name in ("x0_relative", "smooth"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"Sampling: {name} must be True or False, got {getattr(self, name)!r}")
        if _count(self.intervals) < 1:
            raise ValueError(f"Sampling: intervals must be an integer >= 1, got {self.intervals!r}")
        object.__setattr__(self, "intervals", _count(self.intervals))
        if not isinstance(self.integrator, AbstractIntegrator):
            raise ValueError(f"Sampling: integrator must be an integrator such as Heun(), got {self.integrator!r}")

    def record(self) -> dict[str, Any]:
        """Every setting as JSON-ready values (the integrator by its ``label`` and fields)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "integrator"}
        fields = {f.name: getattr(self.integrator, f.name) for f in dataclasses.fields(self.integrator)}
        return {**out, "integrator": {"label": self.integrator.label, "fields": fields}}

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> Sampling:
        """The inverse of :meth:`record`."""
        integ, rec = record["integrator"], {k: v for k, v in record.items() if k != "integrator"}
        if integ["label"] not in INTEGRATORS:
            raise ValueError(f"unknown integrator {integ['label']!r}; expected one of {sorted(INTEGRATORS)}")
        return cls(**rec, integrator=INTEGRATORS[integ["label"]](**integ["fields"]))


class Trajectories(NamedTuple):
    """A batch of trajectories (a pytree): controls (B, N + 1, m) and observed states (B, N + 1, n)."""

    controls: Any
    states: Any


@dataclasses.dataclass(frozen=True, eq=False)
class Dataset:
    """Train, validation and test trajectories on a shared grid ``times`` (N + 1,), with ``system`` (its name),
    ``spec_sha256``, and the ``sampling`` and ``seed`` that regenerate them bit for bit. Construction checks shapes and
    finiteness and keeps read-only float64 copies."""

    times: Any
    train: Trajectories
    validation: Trajectories
    test: Trajectories
    system: str
    spec_sha256: str
    sampling: Sampling
    seed: int

    def __post_init__(self):
        object.__setattr__(self, "times", _frozen(self.times))
        nodes, dims = self.sampling.intervals + 1, set()
        if self.times.shape != (nodes,):
            raise ValueError(f"Dataset: times must have shape ({nodes},), got {self.times.shape}")
        for split in _SPLITS:
            tr = u, x = Trajectories(*(_frozen(a) for a in getattr(self, split)))
            if u.ndim != 3 or x.ndim != 3 or u.shape[:2] != x.shape[:2] or u.shape[1] != nodes:
                raise ValueError(f"Dataset: {split} needs controls (B, {nodes}, m) and states (B, {nodes}, n), got "
                                 f"{u.shape} and {x.shape}")
            dims.add((u.shape[2], x.shape[2]))
            for what, a in zip(tr._fields, tr):
                if not np.all(np.isfinite(a)):
                    raise ValueError(f"Dataset: {split}.{what} holds {a.size - np.isfinite(a).sum()} NaN/inf values")
            object.__setattr__(self, split, tr)
        if len(dims) > 1:
            raise ValueError(f"Dataset: the splits disagree on (n_controls, n_states): {sorted(dims)}")

    n_train = property(lambda self: self.train.states.shape[0])
    n_validation = property(lambda self: self.validation.states.shape[0])
    n_test = property(lambda self: self.test.states.shape[0])
    intervals = property(lambda self: self.times.shape[0] - 1)
    n_states = property(lambda self: self.train.states.shape[2])
    n_controls = property(lambda self: self.train.controls.shape[2])
    horizon = property(lambda self: float(self.times[-1]))


def check_source(dataset: Any, system: System, who: str) -> None:
    """``ValueError`` naming both when ``dataset`` was not generated from ``system``'s spec, or has other dimensions."""
    if dataset.system != system.name:
        raise ValueError(f"{who}: the dataset is of system {dataset.system!r} but the model is of {system.name!r}")
    if dataset.spec_sha256 != system.spec_sha256:
        raise ValueError(f"{who}: the dataset's spec (sha256 {dataset.spec_sha256}) is not the model's {system.name!r} "
                         f"({system.spec_sha256}): regenerate the dataset for this spec")
    xs, us = np.shape(dataset.train.states), np.shape(dataset.train.controls)
    if len(xs) != 3 or len(us) != 3 or xs[0] < 1 or (xs[2], us[2]) != (system.n_states, system.n_controls):
        raise ValueError(f"{who}: {system.name} needs training states (B >= 1, N+1, {system.n_states}) and controls "
                         f"(B, N+1, {system.n_controls}), the dataset has {xs} and {us}")


def _frozen(a: Any) -> np.ndarray:
    a = np.array(a, dtype=np.float64)  # a copy: the caller's array stays theirs
    a.flags.writeable = False
    return a


def sampling_scales(system: System, s: Sampling) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The control-step, start and noise (``noise_scale="range"``) standard deviations; ``ValueError`` naming the
    state or control and the fixes where the sampling needs a bound the system lacks."""
    a = system.arrays()
    ulo, uhi, xlo, xhi, x0 = a["u_lower"], a["u_upper"], a["x_lower"], a["x_upper"], a["x0"]
    needs = []  # (kind, names, lower, upper, indices, why, the fix that needs no bound)
    if s.controls != "around" or s.spread > 0:
        what = {"random_walk": "draws u_0 from U(u_min, u_max) and steps with std spread * (u_max - u_min)",
                "uniform": "draws u from U(u_min, u_max)",
                "around": f"with spread={s.spread} perturbs with std spread * (u_max - u_min)"}[s.controls]
        needs.append(("control", system.control_names, ulo, uhi, range(system.n_controls),
                      f"controls={s.controls!r} {what}", ""))
    if s.x0_relative and s.x0_std > 0:
        needs.append(("state", system.state_names, xlo, xhi, np.flatnonzero(x0 == 0),
                      "x0_relative=True perturbs a state with x0 = 0 by x0_std * (x_max - x_min)",
                      ", or perturb the start by x0_std itself: x0_relative=False"))
    if s.noise > 0 and s.noise_scale == "range":
        needs.append(("state", system.state_names, xlo, xhi, range(system.n_states),
                      f"noise={s.noise} is a fraction of the state range x_max - x_min",
                      ", or take the noise as a fraction of each state's spread in the data: noise_scale='spread'"))
    for kind, names, lo, hi, indices, why, fix in needs:
        for i in indices:
            bad = [f"{side} bound {v[i]}" for side, v in (("lower", lo), ("upper", hi)) if not np.isfinite(v[i])]
            if bad:
                raise ValueError(f"{system.name}: {why}, but {kind} `{names[i]}` has {' and '.join(bad)}; give "
                                 f"`{names[i]}` finite bounds in a copy of the spec{fix}")
    u_scale = s.spread * (uhi - ulo) if s.spread > 0 else np.zeros_like(ulo)
    x0_scale = np.full_like(x0, s.x0_std)
    if s.x0_relative:  # (the range is only selected where x0 = 0, and x0_std = 0 must not make 0 * inf)
        x0_scale = np.where(x0 != 0, s.x0_std * np.abs(x0), s.x0_std * (xhi - xlo) if s.x0_std > 0 else 0.0)
    noise_scale = s.noise * (xhi - xlo) if s.noise > 0 and s.noise_scale == "range" else np.zeros_like(xlo)
    return u_scale, x0_scale, noise_scale


def _smooth(u: jax.Array) -> jax.Array:
    """Two passes of the published 5-tap kernel along time, edges padded with the end values."""
    for _ in range(2):
        padded = jnp.pad(u, ((2, 2), (0, 0)), mode="edge")
        u = sum(float(w) * padded[j:j + u.shape[0]] for j, w in enumerate(_KERNEL))
    return u


@functools.partial(jax.jit, static_argnums=(0, 1, 2))
def _generate(system: System, s: Sampling, batch: int, key, around, u_scale, x0_scale, noise_scale):
    a = {k: jnp.asarray(v) for k, v in system.arrays().items()}
    ulo, uhi, xlo, xhi = a["u_lower"], a["u_upper"], a["x_lower"], a["x_upper"]
    N, m, n, f64 = s.intervals, system.n_controls, system.n_states, jnp.float64
    params = system.default_params(f64)
    # One threefry draw (each costs ~1 s to compile): w ~ U[-1 + eps, 1), U(0,1) = (w + 1) / 2, N(0,1) = sqrt2 erfinv(w)
    sizes = ((N + 1) * m, n, (N + 1) * n if s.noise > 0 else 0)  # controls, start, observation noise
    w = jax.random.uniform(key, (batch, sum(sizes)), f64, np.nextafter(-1.0, 0.0), 1.0)
    z = lambda w: np.sqrt(2.0) * jax.scipy.special.erfinv(w)  # noqa: E731
    u01 = lambda w: jnp.clip(ulo + 0.5 * (w + 1.0) * (uhi - ulo), ulo, uhi)  # noqa: E731  (U(u_min, u_max))
    walk = lambda u, d: (jnp.clip(u + d, ulo, uhi),) * 2  # noqa: E731  (carry and output: the next control)

    def one(w):
        wu, wx, wn = jnp.split(w, np.cumsum(sizes)[:2])
        wu, wn = wu.reshape(N + 1, m), wn.reshape(-1, n)
        if s.controls == "random_walk":
            u = jnp.concatenate([u01(wu[0])[None], jax.lax.scan(walk, u01(wu[0]), z(wu[1:]) * u_scale)[1]])
        elif s.controls == "uniform":
            u = u01(wu)
        else:
            u = jnp.clip(around + z(wu) * u_scale, ulo, uhi)
        u = _smooth(u) if s.smooth else u
        x0 = jnp.clip(a["x0"] + z(wx) * x0_scale, xlo, xhi)
        f = lambda x, uu, t: system.dynamics(x, uu, t, params)  # noqa: E731
        return u, rollout(s.integrator, f, x0, 0.0, float(system.horizon) / N, u), z(wn)

    us, xs, zn = jax.vmap(one)(w)
    if s.noise > 0:
        if s.noise_scale == "spread":  # over the finite values (trajectories that blew up are reported as such)
            finite = jnp.where(jnp.isfinite(xs), xs, jnp.nan)
            noise_scale = s.noise * (jnp.nanmax(finite, axis=(0, 1)) - jnp.nanmin(finite, axis=(0, 1)))
        xs = jnp.clip(xs + zn * noise_scale, xlo, xhi)
    return us, xs


def make_dataset(system: System | str | os.PathLike, sampling: Sampling = Sampling(), *,
                 trajectories: tuple[int, int, int] = (10, 3, 3), seed: int = 0, around: Any = None) -> Dataset:
    """Sample (train, validation, test) trajectories of ``system``'s (a :class:`System`, or a name / spec path) true
    dynamics (see the module docstring); ``around``: the (N + 1, m) controls for ``controls="around"`` only.

    Raises:
        ValueError: a bound the sampling needs is infinite; bad sizes, seed or ``around``; non-finite generated
            trajectories (the true dynamics blew up; the message says how many and which). RuntimeError: no float64.
            UnsupportedFeature: a system with a free final time (no horizon to sample on).
    """
    system = system if isinstance(system, System) else load(system)
    if system.free_horizon:
        # The trajectories are sampled on [0, T]; with a free final time ``system.horizon`` is only the guess of T.
        lo, hi = system.horizon_bounds
        raise UnsupportedFeature(
            f"make_dataset: {system.name} has a free final time (T in [{lo:g}, {hi:g}]), so there is no horizon to "
            f"sample trajectories on (its horizon {system.horizon:g} is only the guess); give the spec a fixed "
            f"horizon for system identification")
    if jax.dtypes.canonicalize_dtype(np.float64) != np.float64:
        raise RuntimeError("make_dataset needs float64: call jax.config.update('jax_enable_x64', True) first")
    sizes, seed = tuple(_count(v) for v in trajectories), _count(seed)
    if len(sizes) != 3 or min(sizes) < 0 or sizes[0] < 1:
        raise ValueError(f"trajectories must be (train >= 1, validation >= 0, test >= 0), got {trajectories!r}")
    if seed < 0:
        raise ValueError("seed must be a non-negative integer")
    N, m = sampling.intervals, system.n_controls
    if (around is None) != (sampling.controls != "around"):
        raise ValueError(f"around= (the controls to sample around) goes with controls='around' and only with it; got "
                         f"controls={sampling.controls!r} and around {'missing' if around is None else 'given'}")
    if around is not None:
        around = np.asarray(around, dtype=np.float64)
        around = around[:, None] if around.ndim == 1 and m == 1 else around
        if around.shape != (N + 1, m) or not np.all(np.isfinite(around)):
            raise ValueError(f"{system.name}: around must be finite controls of shape ({N + 1}, {m}); got shape "
                             f"{around.shape}{'' if np.all(np.isfinite(around)) else ' with NaN/inf values'}")
    scales = sampling_scales(system, sampling)  # every bound check, before any work
    us, xs = map(np.asarray, _generate(system, sampling, sum(sizes), jax.random.key(seed), around, *scales))
    bad = np.flatnonzero(~np.all(np.isfinite(xs), axis=(1, 2)) | ~np.all(np.isfinite(us), axis=(1, 2)))
    if bad.size:
        edges = np.cumsum((0,) + sizes)
        where = ", ".join(f"{_SPLITS[j]}[{i - edges[j]}]" for i in bad for j in [np.searchsorted(edges, i, "right")-1])
        raise ValueError(f"{system.name}: {bad.size} of {sum(sizes)} generated trajectories are not finite ({where}): "
                         f"the true dynamics blew up from the perturbed start or under the sampled controls. Try a "
                         f"smaller spread (now {sampling.spread}) or x0_std (now {sampling.x0_std}), more intervals "
                         f"(now {N}) or the Adaptive integrator if the explicit step is unstable, or another seed")
    train, validation, test = (Trajectories(*p) for p in zip(*(np.split(a, np.cumsum(sizes)[:-1]) for a in (us, xs))))
    return Dataset(np.linspace(0.0, float(system.horizon), N + 1), train, validation, test, system.name,
                   system.spec_sha256, sampling, seed)


def _arrays(d: Dataset) -> dict[str, np.ndarray]:
    return {"times": d.times, **{f"{s}_{w}": getattr(getattr(d, s), w) for s in _SPLITS for w in Trajectories._fields}}


def _digest(arrays: dict[str, np.ndarray], head: bytes = b"") -> str:
    """SHA-256 of ``head``, then each array's name, shape and little-endian float64 bytes, by name."""
    h = hashlib.sha256(head)
    for k in sorted(arrays):
        h.update(f"{k}{np.shape(arrays[k])}".encode() + np.ascontiguousarray(arrays[k], dtype="<f8").tobytes())
    return h.hexdigest()


def save_dataset(dataset: Dataset, path: str | os.PathLike) -> Path:
    """Write ``path`` (``.npz``, the arrays) then its sidecar ``path.with_suffix(".json")`` (the system, spec hash,
    sampling, seed, shapes and the arrays' SHA-256), each atomically; ``load_dataset`` refuses a stale sidecar."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"save_dataset: the path must end in .npz, got {str(path)!r}")
    arrays = _arrays(dataset)
    record = {"format": FORMAT, "version": VERSION, "system": dataset.system, "spec_sha256": dataset.spec_sha256,
              "seed": dataset.seed, "sampling": dataset.sampling.record(), "dtype": "float64",
              "shapes": {k: list(a.shape) for k, a in arrays.items()}, "arrays_sha256": _digest(arrays)}
    text = json.dumps(record, indent=2, allow_nan=False) + "\n"  # serialise before writing anything
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as f:
        np.savez(f, **arrays)
    atomic_write_text(path.with_suffix(".json"), text)
    return path


def load_dataset(path: str | os.PathLike, system: System | str | os.PathLike | None = None) -> Dataset:
    """Read a dataset written by :func:`save_dataset`, checked against its sidecar and ``system`` (if given; another
    spec hash is refused with both named). FileNotFoundError or ValueError for anything else amiss."""
    path = Path(path)
    side = path.with_suffix(".json")
    if not (path.is_file() and side.is_file()):
        raise FileNotFoundError(f"load_dataset: {str(path)!r} and its sidecar {side.name!r} must both exist")
    rec = json.loads(side.read_text(encoding="utf-8"))
    if rec.get("format") != FORMAT or rec.get("version") != VERSION:
        raise ValueError(f"{side}: not a {FORMAT} v{VERSION} sidecar ({rec.get('format')!r} v{rec.get('version')!r})")
    given = system if system is None or isinstance(system, System) else load(system)
    if given is not None and given.spec_sha256 != rec["spec_sha256"]:
        raise ValueError(f"{path}: the dataset was generated from system {rec['system']!r} with spec sha256 "
                         f"{rec['spec_sha256']}, but the given system {given.name!r} has spec sha256 "
                         f"{given.spec_sha256}; regenerate the data for this spec or load the spec the data came from")
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    shapes = {k: tuple(v) for k, v in rec["shapes"].items()}
    if set(arrays) != set(shapes):
        raise ValueError(f"{path}: arrays {sorted(arrays)} do not match the sidecar's {sorted(shapes)}")
    for k, a in arrays.items():
        if a.shape != shapes[k] or a.dtype != np.float64:
            raise ValueError(f"{path}: array {k!r} is {a.dtype} {a.shape}; the sidecar says float64 {shapes[k]}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{path}: array {k!r} holds {a.size - np.isfinite(a).sum()} NaN/inf values")
    if _digest(arrays) != rec["arrays_sha256"]:
        raise ValueError(f"{path}: the arrays are not the ones {side.name} describes (edited, or an interrupted save)")
    splits = (Trajectories(arrays[f"{s}_controls"], arrays[f"{s}_states"]) for s in _SPLITS)
    return Dataset(arrays["times"], *splits, rec["system"], rec["spec_sha256"], Sampling.from_record(rec["sampling"]),
                   rec["seed"])


def dataset_id(dataset: Dataset) -> str:
    """A SHA-256 of what a fit reads from a dataset: system, spec hash, grid, train and validation arrays (the
    identity a checkpoint checks)."""
    arrays = {"times": dataset.times}
    for split in ("train", "validation"):
        tr = getattr(dataset, split)
        arrays[f"{split}.controls"], arrays[f"{split}.states"] = tr.controls, tr.states
    return _digest(arrays, f"{dataset.system}\0{dataset.spec_sha256}\0".encode())
