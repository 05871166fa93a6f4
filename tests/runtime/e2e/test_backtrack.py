"""Backtracking (``E2EConfig.on_failure="backtrack"``) and the interior point's primal-dual warm start inside the
learner: a step whose model the planner cannot solve is taken back and tried again at half the length.

The failing step is made by hand (parameters set to NaN between two compiled iterations), so the test does not
depend on which learning rate happens to break which system."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime import load, solve
from myriad.runtime.e2e import E2EConfig
from myriad.runtime.e2e.step import BACKTRACK, USED, Program
from myriad.runtime.e2e.train import _learnables
from myriad.runtime.learn.models import make_model
from myriad.runtime.solvers import InteriorPoint, Ipopt
from myriad.runtime.solvers.adjoint import Implicit
from myriad.runtime.transcriptions import SingleShooting
from myriad.runtime.transcriptions.base import transcribe

pytestmark = pytest.mark.slow  # not in `make test-fast`: end-to-end learning runs through failing solves

jax.config.update("jax_enable_x64", True)
GRID = SingleShooting(intervals=50)


@pytest.fixture(scope="module")
def program():
    system = load("cancer_treatment")
    expert = solve(system, GRID, Ipopt(), resimulate=False)
    config = E2EConfig(adjoint=Implicit(), implicit_solver=InteriorPoint(), optimizer=1e-2)
    model = make_model(config.model, system, hidden=config.hidden, activation=config.activation)
    train, frozen, consts, _ = _learnables(system, model, config)
    nlp = transcribe(model.as_system(model.combine(train["model"], frozen["model"])), GRID)
    prog = Program(model, nlp, config, expert.controls, expert.states)
    return prog, train, frozen, consts


def _same(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_a_step_the_planner_cannot_solve_is_taken_back_and_halved(program):
    prog, train0, frozen, consts = program
    opt0, carry0 = prog.init_opt(train0), prog.init_carry(train0, frozen, consts)
    no = jnp.asarray(False)
    train1, opt1, carry1, m1 = prog.iteration(train0, opt0, carry0, frozen, consts, no)
    assert USED[int(m1.used)] == "implicit" and bool(carry1.has_good) and float(carry1.scale) == 1.0
    # The next model is one the planner cannot solve (NaN dynamics): back to train0 and its optimiser state.
    poisoned = jax.tree.map(lambda a: a * jnp.nan, train1)
    train2, opt2, carry2, m2 = prog.iteration(poisoned, opt1, carry1, frozen, consts, no)
    assert USED[int(m2.used)] == "backtracked" and bool(m2.finite) and not bool(m2.converged)
    assert _same(train2, train0) and _same(opt2, opt0) and float(carry2.scale) == BACKTRACK
    assert _same(carry2.warm, carry1.warm)  # the next solve starts where the last converged one ended
    # From train0 again: the same update at half the length, and the warm start solves train0 in a step or two.
    train3, _, carry3, m3 = prog.iteration(train2, opt2, carry2, frozen, consts, no)
    assert USED[int(m3.used)] == "implicit" and int(m3.iterations) <= 3, int(m3.iterations)
    for k in train0["model"]:
        full = float(train1["model"][k] - train0["model"][k])
        assert float(train3["model"][k] - train0["model"][k]) == pytest.approx(BACKTRACK * full, rel=1e-9)
    assert float(carry3.scale) > BACKTRACK  # a converged solve lets the step grow back


def test_without_a_converged_solve_there_is_nothing_to_go_back_to(program):
    prog, train0, frozen, consts = program
    opt0, carry0 = prog.init_opt(train0), prog.init_carry(train0, frozen, consts)
    poisoned = jax.tree.map(lambda a: a * jnp.nan, train0)
    train1, _, carry1, m = prog.iteration(poisoned, opt0, carry0, frozen, consts, jnp.asarray(False))
    assert USED[int(m.used)] == "skipped"  # as with on_failure="skip": no update, the run goes on
    assert float(carry1.scale) == 1.0 and not bool(carry1.has_good)
    assert _same(carry1.warm, carry0.warm)
