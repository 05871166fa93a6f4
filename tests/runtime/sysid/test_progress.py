"""Progress lines of a system-identification run without a terminal (issue 33): each phase says it has begun, so the
sampling and the first epoch's compilation are not minutes of silence; ``progress=False`` prints nothing."""

import re

from myriad.runtime.learn.dataset import Sampling
from myriad.runtime.sysid.run import SysidConfig, run_sysid

CONFIG = SysidConfig(trajectories=3, sampling=Sampling(intervals=20))  # bioreactor, parametric, least squares


def test_each_phase_prints_a_line_on_stderr_before_it_runs(capsys):
    report = run_sysid("bioreactor", CONFIG)  # pytest's captured stderr is not a terminal
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.startswith("sysid bioreactor:")]
    assert [re.sub(r", [0-9.]+ s$", "", line) for line in lines] == [
        "sysid bioreactor: phase 1/3, sampling 3 + 3 + 3 trajectories (train, validation, test)",
        "sysid bioreactor: phase 2/3, solving the true optimum (the plan's yardstick)",
        "sysid bioreactor: phase 3/3, round 1/1: fitting by least squares, then planning on the model",
    ]
    seconds = [float(line.rsplit(", ", 1)[1][:-2]) for line in lines]
    assert seconds == sorted(seconds) and seconds[0] < seconds[-1]  # a line as each phase begins, not at the end
    assert captured.out == "" and report.converged


def test_no_progress_prints_nothing(capsys):
    run_sysid("bioreactor", CONFIG, progress=False)
    assert capsys.readouterr().err == ""
