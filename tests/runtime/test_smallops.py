"""smallops: the vmap-friendly products, gathers and scatter-adds equal jnp's, for indices of every kind."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from myriad.runtime.smallops import add_at, matmul, matvec, take

jax.config.update("jax_enable_x64", True)

N, M = 7, 2
INDICES = {
    "single shooting (N, 2m)": np.arange(N)[:, None] * M + np.arange(2 * M)[None, :],
    "permutation": np.array([0, 1, 2, 4, 5, 3]),
    "scattered": np.array([5, 0, 3, 3, 1]),
    "one": np.array([2]),
    "empty": np.zeros(0, dtype=int),
    "column (N, 1)": (np.arange(N) * M + 1)[:, None],
    "3-d": np.arange(24).reshape(2, 3, 4) % 15,
}


@pytest.mark.parametrize("name", sorted(INDICES))
@pytest.mark.parametrize("axis", [0, 1, -1])
def test_take_and_add_at_match_jnp(name, axis):
    index = INDICES[name]
    size = int(index.max()) + 3 if index.size else 4
    rng = np.random.default_rng(0)
    x = rng.normal(size=(3, size, 2) if axis == 1 else (size, 3) if axis == 0 else (2, 3, size))
    x = jnp.asarray(x)
    np.testing.assert_array_equal(take(x, index, axis=axis), jnp.take(x, index, axis=axis))
    values_shape = list(x.shape)
    ax = axis % x.ndim
    values_shape[ax:ax + 1] = index.shape
    values = jnp.asarray(rng.normal(size=values_shape))
    expected = jnp.zeros(x.shape).at[(slice(None),) * ax + (index,)].add(values)
    np.testing.assert_allclose(add_at(size, index, values, axis=ax), expected, rtol=0, atol=1e-14)


def test_under_vmap_and_jit():
    index = INDICES["single shooting (N, 2m)"]
    z = jnp.asarray(np.random.default_rng(1).normal(size=(5, N * M + M)))
    got = jax.jit(jax.vmap(lambda zi: add_at(zi.size, index, take(zi, index))))(z)
    expected = jax.vmap(lambda zi: jnp.zeros_like(zi).at[index].add(zi[index]))(z)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-14)


def test_products_and_errors():
    rng = np.random.default_rng(2)
    a, b, v = rng.normal(size=(4, 3, 5)), rng.normal(size=(4, 5, 2)), rng.normal(size=(4, 5))
    np.testing.assert_allclose(matmul(a, b), a @ b, rtol=0, atol=1e-14)
    np.testing.assert_allclose(matvec(a, v), np.einsum("kij,kj->ki", a, v), rtol=0, atol=1e-14)
    with pytest.raises(IndexError):
        take(jnp.zeros(3), np.array([3]))
    with pytest.raises(TypeError):
        take(jnp.zeros(3), np.array([0.0]))
    with pytest.raises(ValueError, match="index's shape"):
        add_at(4, np.array([0, 1]), jnp.zeros(3))
