"""The shipped specs' declared uncertainty (issue 30 item 5) leaves what was published as it was: no shipped spec asks
for a robust solve (its `solve` and the published table stay nominal), the default env of every shipped system is
the deterministic one (randomisation is opt-in, so the `myriad/<Name>-v0` envs are unchanged), and each declared
range holds the nominal value and says in the spec's description where it comes from."""

import pytest

from myriad.runtime import load
from myriad.runtime.rl.env import Env, EnvOptions
from myriad.runtime.systems import NAMES
from myriad.runtime.uncertainty.distributions import support, uncertain_spec
from myriad.runtime.uncertainty.robust import asks_robust

DECLARED = {"van_der_pol", "pendulum", "cartpole", "mountain_car", "cancer_treatment", "mould_fungicide", "glucose",
            "bacteria", "rocket_landing", "tumour", "hiv_treatment"}


@pytest.mark.parametrize("name", NAMES)
def test_shipped_specs_solve_nominally_and_their_default_envs_are_deterministic(name):
    system = load(name)
    names, kinds, args = uncertain_spec(system)
    assert bool(names) == (name in DECLARED)
    assert not asks_robust(system) and system.process_noise == () and system.observation_noise == ()
    assert not Env(system, EnvOptions()).stochastic  # the default env: nothing drawn, no noise
    assert Env(system, EnvOptions(randomize=True)).randomized == bool(names)
    values = dict(zip(system.param_names, system.param_values))
    for n, k, a in zip(names, kinds, args):
        # the declared numbers themselves: support() rebuilds them as centre + (end - centre), off by an ulp
        lo, hi = (a[0], a[1]) if k == "uniform" else (min(a), max(a)) if k == "choice" else support(k, a)
        assert lo <= values[n] <= hi, (n, values[n], lo, hi)
        assert k != "choice" or values[n] in a, (n, values[n], a)  # a choice's nominal is one of its values
    if names:
        assert "Uncertainty:" in system.description and "range" in system.description
