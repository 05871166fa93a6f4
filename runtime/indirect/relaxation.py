r"""Relaxed sweeps with a step control on the relaxation omega.

One relaxed sweep from the controls u^j (G the sweep map of :mod:`.pontryagin`):

    u^{j+1} = u^j + omega (G(u^j; theta) - u^j)            (omega = 1/2 is Lenhart's average)

Near a fixed point the error obeys e^{j+1} = (I + omega (G' - I)) e^j. Where the eigenvalues mu of G' are real and
<= 0 (H quadratic in u, no active control bound: the sweep is a gradient descent on the cost), the sweep converges
iff omega < 2 / (1 + |mu|_max). Unstable dynamics make |mu|_max grow roughly like e^{2cT} (c the growth rate), so a
fixed omega = 1/2 can diverge; measurements on Van der Pol are in docs/notes/sweep-convergence.md.

Step control: an omega beyond the limit multiplies the dominant error mode by 1 - omega (1 + |mu|) < -1 per sweep,
so successive corrections G(u) - u point apart; omega is halved whenever their inner product is negative, and never
raised. Once omega < 1 / (1 + |mu|) no mode changes sign any more, so (for the linearisation) omega ends within a
factor 4 below the stability limit, found without estimating mu.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from .pontryagin import Problem, relative_change, sweep_map

__all__ = ["relax"]


def relax(p: Problem, theta: Any, u: Any, omega: Any, budget: Any, stop_at: Any) -> tuple[Any, Any, Any, Any]:
    """Relaxed sweeps from u at the terminal costates theta until the change is <= stop_at or ``budget`` sweeps
    are done (a NaN change stops it too: NaN > stop_at is False).

    Returns:
        (u, omega, sweeps, change): the controls, omega as the step control left it, the sweeps done, and the last
        sweep's relative change, measured at its input (inf when no sweep ran).
    """
    int0 = jnp.asarray(0, dtype=jnp.int32)
    inf = jnp.asarray(jnp.inf, dtype=u.dtype)

    def cond(c):
        _, _, _, it, change = c
        return (it < budget) & (change > stop_at)

    def body(c):
        u, d_prev, omega, it, _ = c
        new, _ = sweep_map(p, u, theta)
        d = new - u
        # Beyond the stability limit the most negative eigenvalue's mode flips sign every sweep, so successive
        # corrections point apart: halve omega at each flip (see the module docstring).
        omega = jnp.where(jnp.vdot(d, d_prev) < 0.0, 0.5 * omega, omega)
        return u + omega * d, d, omega, it + 1, relative_change(p, new, u)

    init = (u, jnp.zeros_like(u), omega, int0, inf)
    u, _, omega, it, change = jax.lax.while_loop(cond, body, init)
    return u, omega, it, change
