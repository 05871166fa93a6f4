"""The CLI's user errors at the compiler's standard: exit 2, one line naming the input and the fix, the subcommand's
own usage for a bad flag, did-you-mean for flags, choices and systems; never "internal error". Each case fails before
any system is solved (the unknown names are refused by the loader, the flags by the parser)."""

import pytest

from myriad.runtime.cli import main
from myriad.runtime.loader import load

BAD = [
    (["solve", "van_der_pol", "--intervalls", "50"], ["usage: myriad solve", "--intervalls; did you mean --intervals"]),
    (["solve", "van_der_pol", "--solver", "ipoptt"], ["usage: myriad solve", "'ipoptt'; did you mean ipopt"]),
    (["solve", "van_der_poll"], ["'van_der_poll' is neither", "did you mean van_der_pol"]),
    (["solve", "hypersensitiv"], ["did you mean hypersensitive"]),
    (["solve", "peers/hypersensitiv"], ["did you mean peers/hypersensitive"]),
    (["solve", "no/such/spec.yaml"], ["file not found: no/such/spec.yaml"]),
    (["solve", "van_der_pol", "stray"], ["usage: myriad solve", "argument stray; see myriad solve --help"]),
    (["bench", "--sytems", "pendulum"], ["usage: myriad bench", "did you mean --systems"]),
    (["bench", "--compile", "fast"], ["usage: myriad bench", "invalid choice 'fast'"]),
    (["sweep", "simple_case", "--backnd", "ray"], ["usage: myriad sweep", "did you mean --backend"]),
    (["sweep", "van_der_poll"], ["did you mean van_der_pol"]),
    (["sysid", "van_der_pol", "--modle", "node"], ["usage: myriad sysid", "did you mean --model"]),
    (["sysid", "van_der_pol", "--model", "nod"], ["usage: myriad sysid", "did you mean node"]),
    (["e2e", "van_der_pol", "--losss", "states"], ["usage: myriad e2e", "did you mean --loss"]),
    (["rl-reference", "--chek"], ["usage: myriad rl-reference", "did you mean --check"]),
]


@pytest.mark.parametrize("argv, words", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_input_is_a_usage_error_naming_the_fix(argv, words, capsys):
    with pytest.raises(SystemExit) as stop:
        raise SystemExit(main(argv))
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "internal error" not in err and "Traceback" not in err
    for w in words:
        assert w in err, err
    assert "usage: myriad COMMAND" not in err and "usage: myriad [-h]" not in err  # the subcommand's, not the top's
    assert len([ln for ln in err.splitlines() if ": error: " in ln]) == 1


def test_choices_match_case_insensitively_where_unambiguous(capsys):
    # Refused for its grid, after the parser accepted IPOPT and Trapezoidal as ipopt and trapezoidal.
    argv = ["solve", "van_der_pol", "--solver", "IPOPT", "--transcription", "Trapezoidal", "--intervals", "0"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--intervals must be an integer >= 1" in err and "invalid choice" not in err


def test_systems_resolve_by_bare_peer_name_and_case_insensitively():
    assert load("hypersensitive") is load("peers/hypersensitive")
    assert load("Van_Der_Pol") is load("van_der_pol")
    with pytest.raises(KeyError, match="file not found"):
        load("missing.yaml")


def test_a_misspelt_command_suggests_the_closest_and_any_case_is_taken(capsys):
    with pytest.raises(SystemExit) as stop:  # the parser's own error exits
        main(["solv", "van_der_pol"])
    assert stop.value.code == 2
    assert "invalid choice 'solv'; did you mean solve?" in capsys.readouterr().err
    assert main(["SWEEP", "simple_case", "--backend", "Serial", "--workers", "2"]) == 2  # reached the sweep's checks
    assert "--workers applies to --backend process or ray" in capsys.readouterr().err
