"""Wrong x0 and params are refused before any compile, naming the argument, the expected shape and the names."""

from __future__ import annotations

import pytest

from myriad.runtime import load, solve, solve_batch
from myriad.runtime.data import batch_data, default_data


@pytest.fixture(scope="module")
def cartpole():
    return load("cartpole")


def test_x0_of_the_wrong_length_names_the_states(cartpole):
    with pytest.raises(ValueError, match=r"x0 has 3 values, expected shape \(4,\): cartpole has 4 states \(q1, q2, "):
        solve(cartpole, x0=[1.0, 2.0, 3.0])


def test_x0_of_the_wrong_shape_in_a_batch(cartpole):
    with pytest.raises(ValueError, match=r"x0 has shape \(2, 3\), expected shape \(2, 4\)"):
        solve_batch(cartpole, x0=[[1.0, 2.0, 3.0]] * 2)


def test_unknown_parameter_suggests_the_closest(cartpole):
    with pytest.raises(KeyError, match=r"unknown parameter 'm_1' \(did you mean 'm1'\?\); its parameters are g, m1"):
        solve(cartpole, params={"m_1": 1.0})
    with pytest.raises(KeyError, match="unknown parameter 'zz'; its parameters are"):
        default_data(cartpole, params={"zz": 1.0})


def test_parameter_of_the_wrong_shape(cartpole):
    with pytest.raises(ValueError, match=r"params\['g'\] has shape \(2,\), expected \(\) for cartpole's parameter"):
        solve(cartpole, params={"g": [9.8, 9.81]})
    with pytest.raises(ValueError, match=r"params\['g'\] has shape \(2, 2\), expected \(2,\) \(a leading batch"):
        batch_data(cartpole, params={"g": [[9.8, 9.8], [9.8, 9.8]]})


def test_the_rl_env_checks_its_data_too(cartpole):
    from myriad.runtime.rl import make_jax

    env = make_jax(cartpole)
    with pytest.raises(ValueError, match="x0 has 3 values"):
        env.default_params(x0=[0.0, 0.0, 0.0])


def test_right_shapes_still_pass(cartpole):
    data = default_data(cartpole, params={"g": 9.81}, x0=[0.0, 0.0, 0.0, 0.0])
    assert data.x0.shape == (4,) and data.params["g"].shape == ()
    batch = batch_data(cartpole, params={"g": [9.8, 9.81]}, x0=[[0.0] * 4] * 2)
    assert batch.x0.shape == (2, 4) and batch.params["g"].shape == (2,)


def test_the_gymnasium_envs_check_their_data_too():
    pytest.importorskip("gymnasium")
    from myriad.runtime.rl import MyriadVectorEnv, make

    with pytest.raises(ValueError, match=r"x0 has 3 values, expected shape \(4,\): cartpole has 4 states"):
        make("cartpole", x0=[0.0, 0.0, 0.0])
    with pytest.raises(KeyError, match=r"did you mean 'm1'"):
        make("cartpole", params={"m_1": 1.0})
    with pytest.raises(ValueError, match=r"x0 has shape \(2, 3\), expected shape \(2, 4\)"):
        MyriadVectorEnv("cartpole", num_envs=2, x0=[[0.0] * 3] * 2)
