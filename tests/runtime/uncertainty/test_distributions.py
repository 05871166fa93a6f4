"""The distributions of uncertain parameters: draws against their exact moments (10^4 draws, 3 standard errors),
widen, choice's frequencies, reproducibility and vmap, and malformed declarations."""

import math

import jax
import numpy as np
import pytest

from myriad.runtime.uncertainty import distributions as D

from ._systems import FOUR, assert_moments, declared, four_parameters, plain

M = 10_000


def test_the_compiled_declaration_is_the_specs():
    system = four_parameters()
    assert system.schema == 3 and {k: getattr(system, k) for k in FOUR} == FOUR
    assert D.uncertain_spec(system) == tuple(FOUR.values())


@pytest.mark.parametrize("widen", [1.0, 2.5])
def test_draws_match_the_exact_moments_of_each_widened_distribution(widen):
    system = four_parameters()
    draws = np.asarray(D.sample(system, jax.random.PRNGKey(11), M, widen))
    assert draws.shape == (M, 4) and draws.dtype == np.float64
    assert_moments(draws, FOUR["uncertain_kinds"], FOUR["uncertain_args"], widen)
    for j, (kind, a) in enumerate(zip(FOUR["uncertain_kinds"], FOUR["uncertain_args"])):
        lo, hi = D.support(kind, a, widen)
        assert lo <= draws[:, j].min() and draws[:, j].max() <= hi
    # choice: each value equally likely (binomial standard error), the values moved about their mean by widen
    values = 7 / 6 + widen * (np.array([0.5, 1.0, 2.0]) - 7 / 6)
    counts = np.array([np.sum(np.isclose(draws[:, 3], v, rtol=0, atol=1e-12)) for v in values])
    assert counts.sum() == M and np.all(np.abs(counts / M - 1 / 3) <= 3 * math.sqrt(2 / 9 / M))


def test_widen_zero_is_the_centre_and_the_lognormal_spreads_in_log_space():
    system = four_parameters()
    draws = np.asarray(D.sample(system, jax.random.PRNGKey(0), 5, 0.0))
    centres = [D.centre(k, a) for k, a in zip(FOUR["uncertain_kinds"], FOUR["uncertain_args"])]
    np.testing.assert_allclose(draws, np.tile(centres, (5, 1)), rtol=1e-15)
    assert centres == [2.0, 0.5, 1.0, 7 / 6]
    logs = np.log(np.asarray(D.sample(system, jax.random.PRNGKey(1), M, 2.0))[:, 2])
    assert abs(logs.mean()) <= 3 * 0.5 / math.sqrt(M) and abs(logs.std() - 0.5) <= 3 * 0.5 / math.sqrt(2 * M)


def test_a_row_of_sample_is_draw_of_its_key_and_draw_vmaps_over_keys_and_widen():
    system = four_parameters()
    key = jax.random.PRNGKey(5)
    rows = np.asarray(D.sample(system, key, 3))
    keys = jax.random.split(key, 3)
    np.testing.assert_array_equal(rows[1], np.asarray(D.draw(system, keys[1])))
    widened = jax.jit(jax.vmap(lambda k, w: D.draw(system, k, w)))(keys, np.array([1.0, 1.0, 0.0]))
    np.testing.assert_array_equal(np.asarray(widened)[:2], rows[:2])
    assert np.asarray(D.draw(system, key, dtype=np.float32)).dtype == np.float32
    assert D.draw(plain("four_parameters"), key).shape == (0,)  # nothing declared: nothing drawn


def test_with_values_puts_the_draw_in_place():
    system = four_parameters()
    p = D.with_values(system, system.default_params(), np.array([1.0, 2.0, 3.0, 4.0]))
    assert {k: float(v) for k, v in p.items()} == {"k": 1.0, "c": 2.0, "g": 3.0, "m": 4.0}
    with pytest.raises(ValueError, match="dict of named values"):
        D.with_values(system, [1.0], np.zeros(4))


@pytest.mark.parametrize("attrs, match", [
    ({"uncertain_params": ("k",), "uncertain_kinds": ("uniform",), "uncertain_args": ((2.0, 1.0),)}, "lo < hi"),
    ({"uncertain_params": ("k",), "uncertain_kinds": ("normal",), "uncertain_args": ((2.0, -1.0),)}, "positive"),
    ({"uncertain_params": ("k",), "uncertain_kinds": ("beta",), "uncertain_args": ((2.0, 1.0),)}, "unknown"),
    ({"uncertain_params": ("q",), "uncertain_kinds": ("normal",), "uncertain_args": ((2.0, 1.0),)}, "not a param"),
    ({"uncertain_params": ("k",), "uncertain_kinds": ("choice",), "uncertain_args": ((),)}, "one or more"),
    ({"uncertain_params": ("k", "c"), "uncertain_kinds": ("normal",), "uncertain_args": ((2.0, 1.0),)}, "length"),
])
def test_malformed_declarations_are_refused_by_name(attrs, match):
    with pytest.raises(ValueError, match=match):
        D.draw(declared("four_parameters", **attrs), jax.random.PRNGKey(0))


def test_widen_must_be_non_negative():
    with pytest.raises(ValueError, match="widen"):
        D.sample(four_parameters(), jax.random.PRNGKey(0), 2, -1.0)
