r"""A pure solve with its iteration apart (:class:`Stepper`), and a batch that keeps a fixed number of members in
flight, each finished member's place taken by the next waiting one (:func:`queued`).

A vmapped ``lax.while_loop`` runs until its slowest member stops (the others computed and thrown away until then);
a queue pays that only in the last few iterations, when no member is left waiting (the interior point's README). Each
member still runs exactly the iterations of its own solve, so the results equal the chunked ones.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["Staged", "Stepper", "queued"]


class Stepper(NamedTuple):
    """A pure iterative solve in four pure functions (none jitted; all vmap-able over members).

    Attributes:
        begin: ``(data, z0) -> state`` before the first iteration.
        step: ``(data, state) -> state``, one iteration; on a state that has stopped, a state that is still stopped.
        running: ``state -> bool`` array, whether to step again.
        end: ``(data, state) -> output``, the solve's output at a stopped state.
    """

    begin: Callable[[Any, Any], Any]
    step: Callable[[Any, Any], Any]
    running: Callable[[Any], jax.Array]
    end: Callable[[Any, Any], Any]

    def solve(self, data: Any, z0: Any) -> Any:
        """The whole solve, ``(data, z0) -> output``: one ``lax.while_loop``."""
        state = jax.lax.while_loop(self.running, lambda s: self.step(data, s), self.begin(data, z0))
        return self.end(data, state)


class Staged(NamedTuple):
    """A pure solve as two programs, the second compiled only when a solve needs it (``lax.cond`` compiles both
    branches): ``first`` runs every solve and stops those that need the rest's code; ``rest`` resumes them from the
    state ``first`` stopped at. The outputs equal ``rest``'s solve from the start (``first``'s iterations are its
    own, up to where it stops).

    Attributes:
        first: a stepper whose ``end`` gives ``(output, state)``.
        rest: a stepper whose ``begin`` takes ``(data, state)``, a state of ``first``'s; a state that ``first``
            stopped for good stays stopped.
        pending: ``output -> bool`` NumPy array (on the host, one per member): whether ``first`` stopped the solve
            for ``rest``.
    """

    first: Stepper
    rest: Stepper
    pending: Callable[[Any], Any]


def queued(stepper: Stepper, slots: int) -> Callable[[Any, Any], Any]:
    """``jax.vmap(stepper.solve)`` for a batch ``(data, z0)`` as one program with at most ``slots`` members vmapped at a
    time: after each vmapped iteration the members that stopped write their output and the next waiting members
    begin in their places, until every member has stopped."""
    def run(data, z0):
        size = z0.shape[0]
        if size <= slots:
            return jax.vmap(stepper.solve)(data, z0)
        take = lambda idx: jax.tree.map(lambda a: a[idx], data)  # noqa: E731
        owner = jnp.arange(slots)  # the member in each place; `size` once the place is empty
        places = take(owner)
        state = jax.vmap(stepper.begin)(places, z0[owner])
        shapes = jax.eval_shape(jax.vmap(stepper.end), places, state)
        outputs = jax.tree.map(lambda s: jnp.zeros((size, *s.shape[1:]), s.dtype), shapes)

        def refill(carry):
            state, places, owner, waiting, outputs, stopped = carry
            out = jax.vmap(stepper.end)(places, state)
            where = jnp.where(stopped, owner, size)  # the others' rows fall outside and are dropped
            outputs = jax.tree.map(lambda o, v: o.at[where].set(v, mode="drop"), outputs, out)
            # The stopped places take the next waiting members in order.
            new = waiting + jnp.cumsum(stopped) - 1
            fill = stopped & (new < size)
            next_member = jnp.minimum(new, size - 1)  # places left empty read the last member, then drop it
            new_places = take(next_member)
            fresh = jax.vmap(stepper.begin)(new_places, z0[next_member])
            pick = lambda a, b: jnp.where(fill.reshape(fill.shape + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
            state, places = jax.tree.map(pick, fresh, state), jax.tree.map(pick, new_places, places)
            owner = jnp.where(stopped, jnp.where(fill, new, size), owner)
            return state, places, owner, waiting + jnp.sum(stopped), outputs

        def body(carry):
            state, places, owner, waiting, outputs = carry
            state = jax.vmap(stepper.step)(places, state)
            stopped = (owner < size) & ~jax.vmap(stepper.running)(state)
            return jax.lax.cond(jnp.any(stopped), refill, lambda c: c[:-1],
                                (state, places, owner, waiting, outputs, stopped))

        carry = (state, places, owner, jnp.asarray(slots, owner.dtype), outputs)
        return jax.lax.while_loop(lambda c: jnp.any(c[2] < size), body, carry)[4]

    return run
