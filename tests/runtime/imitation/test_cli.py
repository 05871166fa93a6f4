"""`myriad imitate`'s flags are ImitateConfig's (runtime/configs.py derives them), and bad values are usage errors
(exit 2) naming the flag, before any work."""

import pytest

from myriad.runtime import cli
from myriad.runtime.configs import from_args
from myriad.runtime.imitation import DaggerConfig, FitConfig, ImitateConfig


def test_the_flags_and_set_build_the_config():
    args = cli._parser().parse_args(["imitate", "van_der_pol", "--method", "dagger", "--demos", "5", "--seed", "2",
                                     "--noise", "0.05", "--set", "fit.epochs=7", "--set", "dagger.beta=0.5"])
    config = from_args(ImitateConfig, args)
    assert config == ImitateConfig(method="dagger", demos=5, seed=2, noise=0.05, fit=FitConfig(epochs=7),
                                   dagger=DaggerConfig(beta=0.5))


@pytest.mark.parametrize("argv, flag", [
    (["--demos", "0"], "--demos"),
    (["--seed", "-1"], "--seed"),
    (["--held-out", "1"], "--held-out"),
    (["--set", "dagger.beta=2"], "dagger.beta"),
    (["--set", "fit.learning_rate=0"], "fit.learning_rate"),
    (["--dataset", "/nonexistent/data"], "--dataset"),
])
def test_bad_values_are_usage_errors_naming_the_flag(argv, flag, capsys):
    assert cli.main(["imitate", "van_der_pol", *argv]) == 2
    assert flag in capsys.readouterr().err
