r"""The pure-JAX solver tier: solvers whose whole solve is one JAX function ``(data, z0) -> output`` of a problem (an
:class:`~myriad.runtime.nlp.NLP`, or a system for an indirect method): the tier that a learner differentiates through,
an RL environment calls, and a GPU runs in batches. This base writes once the single solve (compile and solve time
measured apart) and :meth:`AbstractPureSolver.solve_batch` (one program; the solver's ``batch_*`` hooks say how).

Differentiation. Forward mode (``jax.jvp``) goes through the solves' ``lax.while_loop``; reverse mode does not (JAX's
``ValueError``, never a silent zero). Reverse mode in ``data`` comes from the one implicit-function rule on the KKT
conditions (:mod:`.implicit`): the interior point's pure solve carries it, and an NLP solver's ``differentiable_solve``
is its pure solve with it. Unrolling is a ``lax.scan`` of the extragradient stepper's ``iterate``; a learner picks one
by an adjoint object (:mod:`.adjoint`).
"""

from __future__ import annotations

import abc
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation import CompiledFunction, compile_many, program_key, programs
from ..compilation.blas import one_blas_thread
from ..data import require_float64
from ..nlp import NLP, NLPResult
from ..status import Status
from .base import (
    AbstractNLPSolver,
    cached,
    canonical_data,
    constraint_violation,
    constraint_violations,
    initial_point,
    unstack,
)
from .stepper import Staged, Stepper, queued

__all__ = ["AbstractPureSolver", "PureNLPSolver", "ScaledEvaluation"]


class ScaledEvaluation:
    """The objective and constraints of a scaled problem in the *unscaled* ``z``, compiled once as one program: what a
    pure solver evaluates on the host to report a result (its cost and constraint violation)."""

    def __init__(self, problem: Any):
        self.problem = problem
        evaluate, scale = problem.evaluate, jnp.asarray(problem.scale)
        # One program for both (a shooting NLP's F and c share a rollout): one dispatch per report, not two.
        def unscaled(z, data):
            return evaluate(z / scale, data)

        self.evaluate = CompiledFunction(unscaled, program_key(problem.key, "evaluate"))
        self.evaluate_batch = CompiledFunction(jax.vmap(unscaled), program_key(problem.key, "evaluate:batch"))

    def values_batch(self, z: np.ndarray, batched_data: Any, nlp: Any) -> list[tuple[float, np.ndarray | None, float]]:
        """``(F(z), c(z), violation)`` of each member (``z`` (B, n), every leaf of ``batched_data`` batched), from one
        vmapped program, with each member's :func:`~.base.constraint_violation` of ``nlp`` computed for all at once
        (not a dispatch per member: measured in the solver-code note)."""
        self.evaluate_batch.compile(z, batched_data)
        f, c = (np.asarray(a) for a in self.evaluate_batch(z, batched_data))
        constrained = bool(self.problem.n_constraints)
        violation = constraint_violations(nlp, z, c if constrained else None)
        return [(float(f[i]), c[i] if constrained else None, float(violation[i])) for i in range(z.shape[0])]


class _Programs:
    """The jitted solve of one (problem, solver) pair: for callers, for one member, and for a batch (vmapped, or
    mapped: ``strategy``; spread over the default backend's ``devices`` when there are several). With ``staged``
    (and ``staged_batch``), one member and a batch run in two programs, the second compiled at its first need
    (:class:`_TwoStage`); callers' ``jitted`` solve stays one program."""

    def __init__(self, raw: Callable[[Any, Any], Any], key: str | None = None, strategy: str = "vmap",
                 raw_batch: Callable[[Any, Any], Any] | None = None, chunk: int | None = None,
                 stepper: Stepper | None = None, staged: Staged | None = None, staged_batch: Staged | None = None):
        self.jitted = jax.jit(raw)
        self.single = _TwoStage.of(raw, key, "single", staged)
        member = raw if raw_batch is None else raw_batch
        # A program for several devices is not kept in the program store: an exported one can only be called with
        # its inputs already placed on those devices (the host's arrays are not).
        devices = jax.devices()
        store = len(devices) < 2
        if staged_batch is None:
            batched, label = _batched(member, strategy, chunk, stepper)
            self.batched = _TwoStage(CompiledFunction(_across(batched, devices),
                                                      program_key(key, f"batched:{label}:{chunk}") if store else None))
            return
        first, label = _batched(staged_batch.first.solve, strategy, chunk, staged_batch.first if stepper else None)
        # The rest runs few members: all in place, each chunk's loop only as long as its members need.
        rest, _ = _batched(staged_batch.rest.solve, strategy, chunk, None)
        keys = [program_key(key, f"batched:{label}:{chunk}:{part}") if store else None for part in ("first", "rest")]
        self.batched = _TwoStage(CompiledFunction(_across(first, devices), keys[0]),
                                 CompiledFunction(_across(rest, devices), keys[1]), staged_batch.pending)


def _batched(member: Callable[[Any, Any], Any], strategy: str, chunk: int | None,
             stepper: Stepper | None) -> tuple[Callable[[Any, Any], Any], str]:
    """A batch's solve of ``member`` (its ``(data, z0)`` batched on every leaf) and the strategy's label: mapped,
    queued (a vmapped ``stepper`` in chunks) or vmapped in chunks."""
    if strategy != "vmap":
        return (lambda data, z0: jax.lax.map(lambda one: member(*one), (data, z0))), strategy
    if stepper is not None and chunk is not None:
        return queued(stepper, chunk), "queue"
    return _vmapped_in_chunks(member, chunk), strategy


class _TwoStage:
    """A solve's compiled program, or its two (:class:`~.stepper.Staged`): ``first`` for every call, and ``rest``,
    compiled at the first call that needs it (the same shapes never compile twice), for the members ``first``
    stopped for it. A call gives ``(output, compile seconds spent on rest)``."""

    def __init__(self, first: CompiledFunction, rest: CompiledFunction | None = None,
                 pending: Callable[[Any], Any] | None = None):
        self.first, self.rest, self.pending = first, rest, pending

    @classmethod
    def of(cls, raw: Callable[[Any, Any], Any], key: str | None, role: str, staged: Staged | None) -> _TwoStage:
        if staged is None:
            return cls(CompiledFunction(raw, program_key(key, role)))
        return cls(CompiledFunction(staged.first.solve, program_key(key, f"{role}:first")),
                   CompiledFunction(staged.rest.solve, program_key(key, f"{role}:rest")), staged.pending)

    def __call__(self, data: Any, z0: Any) -> tuple[Any, float]:
        out = self.first(data, z0)
        if self.rest is None:
            return out, 0.0
        out, state = out
        pending = self.pending(out)
        if not np.any(pending):
            return out, 0.0
        seconds = self.rest.compile(data, state)
        more = jax.device_get(self.rest(data, state))
        if np.ndim(pending) == 0:
            return more, seconds
        # Members the first program finished keep its output (the rest's would be the same values).
        pick = lambda a, b: np.where(pending.reshape(pending.shape + (1,) * (np.ndim(a) - 1)), a, b)  # noqa: E731
        return jax.tree.map(pick, more, jax.device_get(out)), seconds


def _across(batched: Callable[[Any, Any], Any], devices: list) -> Callable[[Any, Any], Any]:
    """``batched`` with the batch split evenly over ``devices`` (``jax.shard_map``; the last member repeated to fill
    the last share, its copies dropped), each device running ``batched`` on its share at the same time (on a CPU:
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N``). One device: ``batched`` itself."""
    if len(devices) < 2:
        return batched
    mesh = jax.sharding.Mesh(np.array(devices), ("members",))
    spec = jax.sharding.PartitionSpec("members")

    def run(data, z0):
        size, count = _size(z0), len(devices)
        if size < count:
            return batched(data, z0)
        padded = _pad((data, z0), -size % count)
        out = jax.shard_map(batched, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False)(*padded)
        return jax.tree.map(lambda x: x[:size], out)

    return run


def _vmapped_in_chunks(member: Callable[[Any, Any], Any], chunk: int | None) -> Callable[[Any, Any], Any]:
    """``jax.vmap(member)``, or, for a batch larger than ``chunk``, the members vmapped in equal chunks of at most
    ``chunk``, one chunk after another (``jax.lax.map``'s ``batch_size``; the last member repeated to fill the last
    chunk, its copies dropped): one program either way, and a chunk's loop stops with its own slowest member."""
    def run(data, z0):
        size = _size(z0)
        if chunk is None or size <= chunk:
            return jax.vmap(member)(data, z0)
        count = -(-size // chunk)
        width = -(-size // count)
        out = jax.lax.map(lambda one: member(*one), _pad((data, z0), count * width - size), batch_size=width)
        return jax.tree.map(lambda x: x[:size], out)

    return run


def _size(z0: Any) -> int:
    """The number of members of a batch's starts (an array, or a tree of them: a staged solve's states)."""
    return jax.tree.leaves(z0)[0].shape[0]


def _pad(tree: Any, pad: int) -> Any:
    """Every leaf with its last member repeated ``pad`` more times (the filler of a last chunk or device share)."""
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)]), tree) if pad else tree


class AbstractPureSolver(abc.ABC):
    """A solver whose solve is a pure JAX function ``(data, z0) -> output`` of a problem: subclasses (frozen
    dataclasses: the programs are cached per problem and configuration) provide :meth:`pure_solve`, :meth:`start`
    and :meth:`report`; this base provides :meth:`solve_fn`, :meth:`solve_batch` and ``_solve_single``."""

    @abc.abstractmethod
    def pure_solve(self, problem: Any) -> Callable[[Any, Any], Any]:
        """The un-jitted pure solve ``(data, z0) -> output`` for ``problem`` (built once; this base jits it).

        It must not hold a reference to ``problem`` when ``problem`` is an NLP (the cache is keyed weakly by it)."""

    @abc.abstractmethod
    def start(self, problem: Any, data: Any, z0: Any = None) -> np.ndarray:
        """``z0`` checked (``ValueError`` for the wrong shape) as a float64 host array, or the default start for one
        member's ``data`` when None."""

    @abc.abstractmethod
    def report(self, problem: Any, output: Any, data: Any, compile_seconds: float, solve_seconds: float) -> Any:
        """One member's output (host arrays) as the solver's result object."""

    def report_programs(self, problem: Any, z0: np.ndarray, data: Any, batch: bool = False) -> list[tuple]:
        """What :meth:`report` (``batch``: :meth:`batch_values`, for the batch's ``z0`` and ``data``) evaluates, as
        ``(CompiledFunction, args)`` jobs: they compile beside the solve's program (:func:`compile_many`: XLA in
        parallel threads). None by default."""
        return []

    def batch_values(self, problem: Any, output: Any, batched_data: Any) -> list | None:
        """What :meth:`report` evaluates, for every member of a batch's ``output`` at once (passed to it as
        ``values``), or None: each report evaluates its own."""
        return None

    def batch_strategy(self, problem: Any = None) -> str:
        """How :meth:`solve_batch` runs its members in one program: ``"vmap"`` (the default) or ``"map"`` (in turn,
        ``jax.lax.map``: for a solver whose members' work does not vectorise on the backend at hand); ``problem``
        (when given) lets the answer depend on what the solver can exploit in it."""
        return "vmap"

    def batch_chunk(self, problem: Any = None) -> int | None:
        """A vmapped batch runs in chunks of at most this many members, one chunk after another, or all at once
        (None, the default): on a CPU a chunk whose working set stays in cache can beat one wide batch."""
        return None

    def batch_stepper(self, problem: Any) -> Stepper | None:
        """:meth:`pure_solve_batch`'s solve with its iteration apart, or None (the default): with it, a chunked vmapped
        batch is a queue (:func:`~.stepper.queued`) instead of chunks one after another."""
        return None

    def staged(self, problem: Any, batch: bool = False) -> Staged | None:
        """The solve (``batch``: :meth:`pure_solve_batch`'s) as two programs, the second compiled only when a solve
        needs it (:class:`~.stepper.Staged`), or None (the default): one program. Used by :meth:`solve` and
        :meth:`solve_batch`; :meth:`solve_fn` stays one program (a caller's ``jit``, ``grad`` or ``vmap`` of it
        cannot stop between two)."""
        return None

    def pure_solve_batch(self, problem: Any) -> Callable[[Any, Any], Any]:
        """The pure solve that :meth:`solve_batch` maps or vmaps: :meth:`pure_solve`'s unless the solver has a form
        that suits a batch better (the same results)."""
        return self.pure_solve(problem)

    # ---- written once ------------------------------------------------------------------------------------------

    def solve_fn(self, problem: Any) -> Callable[[Any, Any], Any]:
        """The jit-compiled pure solve ``(data, z0) -> output`` (cached per problem and solver; differentiable as the
        module docstring says), a plain ``jax.jit``: pass data whose leaves are arrays of fixed dtype (``default_data``
        / ``batch_data`` build such data), or a Python float in place of an array traces a second program."""
        return self._programs(problem).jitted

    @one_blas_thread()  # also for a solver called directly (an MPC, the RL plans): compilation/blas.py
    def solve_batch(self, problem: Any, batched_data: Any, z0: Any = None) -> list:
        """Solve ``problem`` for a batch of ``data`` (every leaf with a leading axis of size ``B``) as one program.

        With ``vmap`` the loop runs until every member has stopped; members that stop early are frozen by ``vmap``'s
        select, so each result equals its single solve, and each has its own status. With ``map``
        (:meth:`batch_strategy`) the program solves the members one after another.

        ``z0``: None (each member's default start), one start for all, or one per member. Returns ``B`` results whose
        ``compile_seconds`` and ``solve_seconds`` are the batch's totals divided by ``B`` (their sums are the totals).
        """
        programs = self._programs(problem)
        batched_data = canonical_data(batched_data)
        sizes = {np.shape(x)[0] if np.ndim(x) else None for x in jax.tree.leaves(batched_data)}
        if len(sizes) != 1 or None in sizes:
            raise ValueError(f"solve_batch: every leaf of batched_data needs the same leading axis, got {sizes}")
        (batch,) = sizes
        host = jax.device_get(batched_data)  # slice on the host: per-member device slicing dominated small batches
        members = unstack(host, batch)
        if z0 is None:
            z0 = np.stack([self.start(problem, d) for d in members])
        z0 = np.asarray(z0, dtype=np.float64)
        one = np.asarray(self.start(problem, members[0])).shape
        z0 = np.broadcast_to(z0, (batch, *one)).copy()

        compile_seconds = compile_many([(programs.batched.first, (batched_data, z0)),
                                        *self.report_programs(problem, z0, batched_data, batch=True)])
        start = time.perf_counter()
        out, more = programs.batched(batched_data, z0)
        out = jax.device_get(jax.block_until_ready(out))
        solve_seconds = time.perf_counter() - start - more
        compile_seconds += more
        values = self.batch_values(problem, out, batched_data)
        outs = unstack(out, batch)
        return [
            self.report(problem, outs[i], members[i], compile_seconds / batch,
                        solve_seconds / batch, **({} if values is None else {"values": values[i]}))
            for i in range(batch)
        ]

    @one_blas_thread()
    def _solve_single(self, problem: Any, data: Any, z0: Any = None) -> Any:
        """One solve with its compile time measured apart; the subclass's ``solve`` calls this."""
        programs = self._programs(problem)
        data = canonical_data(data)
        z0 = self.start(problem, data, z0)
        compile_seconds = compile_many([(programs.single.first, (data, z0)), *self.report_programs(problem, z0, data)])
        start = time.perf_counter()
        out, more = programs.single(data, z0)
        out = jax.block_until_ready(out)
        solve_seconds = time.perf_counter() - start - more
        compile_seconds += more
        return self.report(problem, out, data, compile_seconds, solve_seconds)

    def _programs(self, problem: Any) -> _Programs:
        require_float64(f"the pure solver {self.label}")  # every pure solve passes here, also one called directly
        strategy, chunk = self.batch_strategy(problem), self.batch_chunk(problem)
        return cached(problem, ("pure", self, strategy, chunk), lambda: _Programs(
            self.pure_solve(problem), program_key(getattr(problem, "key", None), programs.describe(self)),
            strategy, self.pure_solve_batch(problem), chunk,
            self.batch_stepper(problem) if strategy == "vmap" else None, self.staged(problem),
            self.staged(problem, batch=True)))


class PureNLPSolver(AbstractPureSolver, AbstractNLPSolver):
    """An NLP solver of the pure tier: what the extragradient and the interior point share. Its compiled parts for an
    NLP (:meth:`_compiled`) are a :class:`ScaledEvaluation`, so a report re-evaluates the objective and violation at
    ``z`` on the host; the solver says only how its output maps to a :class:`~myriad.runtime.status.Status`."""

    @abc.abstractmethod
    def _compiled(self, nlp: NLP) -> ScaledEvaluation:
        """The solver's compiled parts for ``nlp`` (cached per NLP and configuration)."""

    @abc.abstractmethod
    def outcome(self, out: Any, z: np.ndarray, objective: float, violation: float) -> tuple[Status, int, str]:
        """``(status, solver_code, message)`` of one member's output, given its host-side objective and violation."""

    def solve(self, nlp: NLP, data: Any, z0: Any = None) -> NLPResult:
        return self._solve_single(nlp, data, z0)

    def start(self, nlp: NLP, data: Any, z0: Any = None) -> np.ndarray:
        return initial_point(nlp, data, z0)

    def report_programs(self, nlp: NLP, z0: np.ndarray, data: Any, batch: bool = False) -> list[tuple]:
        fns = self._compiled(nlp)
        return [(fns.evaluate_batch if batch else fns.evaluate, (z0, data))]

    def batch_values(self, nlp: NLP, out: Any, batched_data: Any) -> list:
        return self._compiled(nlp).values_batch(np.asarray(out.z), batched_data, nlp)

    def report(self, nlp: NLP, out: Any, data: Any, compile_seconds: float, solve_seconds: float,
               values: tuple | None = None) -> NLPResult:
        """One member's NLPResult: objective and violation re-evaluated at ``z`` on the host (or the batch's
        ``values``), the status from :meth:`outcome`."""
        fns = self._compiled(nlp)
        z = np.asarray(out.z)
        if values is None:
            f, c = fns.evaluate(z, data)
            objective, c = float(f), (np.asarray(c) if fns.problem.n_constraints else None)
            violation = constraint_violation(nlp, z, c)
        else:  # the batch's (batch_values)
            objective, c, violation = values
        status, code, message = self.outcome(out, z, objective, violation)
        return NLPResult(
            z=z,
            objective=objective,
            status=status,
            solver_code=code,
            message=message,
            iterations=int(out.iterations),
            constraint_violation=violation,
            multipliers=np.asarray(out.multipliers) if fns.problem.n_constraints else None,
            compile_seconds=compile_seconds,
            solve_seconds=solve_seconds,
        )
