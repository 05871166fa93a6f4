"""Table E's aggregation (rliable's IQM and stratified bootstrap, against hand-computed cases and SciPy) and its
resume (a killed table keeps its finished rows and a rerun runs only the rest); one real run on a small system."""

import json

import numpy as np
import pytest
import scipy.stats

from bench import imitation_table as te


def test_iqm_is_the_mean_of_the_middle_half():
    assert te.iqm([100.0, 1, 7, 2, 6, 3, 5, 4]) == pytest.approx(4.5)  # drops 1, 2 and 7, 100: mean of 3, 4, 5, 6
    assert te.iqm([3.0, 1.0, 8.0]) == pytest.approx(4.0)  # floor(3 / 4) = 0 dropped: the mean
    x = np.random.default_rng(0).normal(size=(5, 37))
    np.testing.assert_allclose(te.iqm(x, axis=1), scipy.stats.trim_mean(x, 0.25, axis=1), rtol=1e-14)
    with pytest.raises(ValueError, match="empty"):
        te.iqm([])


def test_stratified_bootstrap_by_hand():
    # Task A's runs {0, 1}, task B's {2, 2}: the mean of the four is (a1 + a2 + 4) / 4 with a1 + a2 in {0, 1, 2}
    # (probabilities 1/4, 1/2, 1/4), so the 95 % percentile interval is [1, 1.5] exactly.
    assert te.stratified_bootstrap_ci([[0.0, 1.0], [2.0, 2.0]], np.mean, reps=4000) == (1.0, 1.5)
    # Not stratified (the four runs pooled as one task) the draws can mix the tasks: a wider interval.
    lo, hi = te.stratified_bootstrap_ci([[0.0, 1.0, 2.0, 2.0]], np.mean, reps=4000)
    assert lo < 1.0 and hi > 1.5
    assert te.stratified_bootstrap_ci([[5.0], [7.0]], te.iqm) == (6.0, 6.0)  # one run per task: nothing to resample
    with pytest.raises(ValueError, match="every task"):
        te.stratified_bootstrap_ci([[1.0], []])


@pytest.mark.parametrize("statistic", ["mean", "iqm"])
def test_one_stratum_agrees_with_scipy_bootstrap(statistic):
    x = np.random.default_rng(1).normal(size=13)
    ours = te.stratified_bootstrap_ci([x], np.mean if statistic == "mean" else te.iqm, reps=20_000)
    fn = np.mean if statistic == "mean" else (lambda a, axis=-1: scipy.stats.trim_mean(a, 0.25, axis=axis))
    ref = scipy.stats.bootstrap((x,), fn, method="percentile", n_resamples=20_000, random_state=0).confidence_interval
    width = ref.high - ref.low
    assert ours == pytest.approx((ref.low, ref.high), abs=0.03 * width)  # two Monte Carlo estimates of one interval


def test_summarise_leaves_failed_runs_out_and_counts_them():
    s = te.summarise([[10.0, None, 30.0, float("nan")]])
    assert (s["iqm"], s["runs"], s["finite"]) == (20.0, 4, 2)
    assert te.summarise([[None]]) == {"iqm": None, "ci": None, "runs": 1, "finite": 0}


class Killed(KeyboardInterrupt):  # a kill (Ctrl-C, as SIGTERM ends a process) is no Exception: never a failed row
    pass


def fake_runner(calls, kill_after=None):
    """A learner runner that scores seed s as 10 (s + 1) (90 for seed 3) without training anything."""

    def run(system, demos, seed, methods, base, separate_bc=False):
        if kill_after is not None and len(calls) == kill_after:
            raise Killed
        calls.append((system, demos, seed, tuple(methods)))
        score = 90.0 if seed == 3 else 10.0 * (seed + 1)
        return [{"system": system, "method": m, "demos": demos, "seed": seed, "status": "max_epochs", "seconds": 2.0,
                 "normalized_score": score + (1.0 if m == "dagger" else 0.0)} for m in methods]

    return run


def test_a_killed_table_keeps_its_rows_and_a_rerun_runs_the_rest(tmp_path):
    path = str(tmp_path / "table.json")
    args = te.parse(["--systems", "simple_case", "--demos", "1", "10", "--seeds", "0", "1", "2", "3",
                  "--methods", "bc", "dagger", "--json", path])
    settings = {"fit": "tiny"}

    def fresh():
        results = te.Results(path, settings)
        results.baseline("simple_case").update(mpc={"score": 99.5, "seconds": 1.0}, ppo={"status": "not installed"},
                                               optimum={"cost": -1.35, "agreement": 0.0, "tolerance": 1e-6})
        return results

    calls = []
    with pytest.raises(Killed):
        te.run_table(args, None, fresh(), ["bc", "dagger"], runner=fake_runner(calls, kill_after=3), progress=False)
    with open(path, encoding="utf-8") as f:
        kept = json.load(f)["rows"]
    assert len(calls) == 3 and len(kept) == 6  # three (demos, seed) jobs, BC and DAgger each
    rerun = []
    results = te.run_table(args, None, fresh(), ["bc", "dagger"], runner=fake_runner(rerun), progress=False)
    assert [(d, s) for _, d, s, _ in rerun] == [(1, 3), (10, 0), (10, 1), (10, 2), (10, 3)]
    assert len(results.data["rows"]) == 16
    again = []
    te.run_table(args, None, fresh(), ["bc", "dagger"], runner=fake_runner(again), progress=False)
    assert again == []  # nothing left
    with pytest.raises(ValueError, match="other settings"):
        te.Results(path, {"fit": "other"})
    grown = te.Results(path, {"fit": "tiny", "e2e": "new"})  # a field ImitateConfig gained since: its default
    assert len(grown.data["rows"]) == 16 and grown.done("simple_case", "bc", 10, 3)

    agg = te.aggregate(results, ["simple_case"], ["bc", "dagger"], [1, 10])
    cell = agg["per"]["simple_case|bc|10"]
    assert cell["iqm"] == pytest.approx(25.0)  # seeds' 10, 20, 30, 90: the middle two
    assert agg["per"]["simple_case|dagger|1"]["iqm"] == pytest.approx(26.0)
    assert cell["ci"][0] <= 25.0 <= cell["ci"][1] and cell["ci"][1] <= 90.0
    assert agg["overall"]["mpc"]["iqm"] == 99.5
    text = te.markdown(results, ["simple_case"], ["bc", "dagger"], [1, 10], {"simple_case": "Simple Case"})
    assert "| | bc | 25.000 [" in text and "| Simple Case | " in text and "1: yes, 10: yes" in text


@pytest.mark.slow  # a real table: demonstrations, a fit, DAgger, MPC (about a minute of compiling)
def test_a_real_row_and_bc_from_dagger_is_bc(tmp_path):
    import dataclasses

    from myriad.runtime.imitation import ImitateConfig, run_imitation
    from myriad.runtime.learn.loop import Stop

    out = tmp_path / "t"
    tiny = ["--set", "fit.epochs=20", "--set", "dagger.iterations=1", "--set", "dagger.rollouts=1"]
    te.main(["--systems", "simple_case", "--demos", "2", "--seeds", "0", "--methods", "bc", "dagger", "--skip-ppo",
          "--no-progress", "--json", f"{out}.json", "--markdown", f"{out}.md", "--png", f"{out}.png", *tiny])
    data = json.loads((tmp_path / "t.json").read_text())
    rows = {r["method"]: r for r in data["rows"]}
    assert set(rows) == {"bc", "dagger"} and Stop(rows["dagger"]["status"]).success
    base = dataclasses.replace(ImitateConfig(), fit=dataclasses.replace(ImitateConfig().fit, epochs=20))
    bc = run_imitation("simple_case", dataclasses.replace(base, method="bc", demos=2, seed=0), progress=False)
    assert rows["bc"]["normalized_score"] == pytest.approx(bc.record()["normalized_score"], rel=1e-12, abs=1e-12)
    assert rows["dagger"]["normalized_score"] >= rows["bc"]["normalized_score"]  # the best iterate, BC's included
    b = data["baselines"]["simple_case"]
    assert b["optimum"]["score"] == 100.0 and b["optimum"]["agreement"] <= b["optimum"]["tolerance"]
    assert b["mpc"]["score"] > 99.0 and "ppo" not in b  # --skip-ppo: left for a later run (minutes a seed)
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| Simple Case | optimum | 100 by definition: J* = -1.3543487;" in (tmp_path / "t.md").read_text()


def test_a_method_that_does_not_apply_is_said_so_not_scored(tmp_path):
    results = te.Results(str(tmp_path / "t.json"), {})
    why = "simple_case declares no learnable parameters, so --method e2e has no model to learn"
    results.add(*(te.refused("simple_case", "e2e", 1, s, why) for s in (0, 1, 2)))
    agg = te.aggregate(results, ["simple_case"], ["e2e"], [1])
    assert agg["per"]["simple_case|e2e|1"]["refused"] == why and "e2e|1" not in agg["overall"]
    text = te.markdown(results, ["simple_case"], ["e2e"], [1], {"simple_case": "Simple Case"})
    assert "| | e2e | does not apply (no learnable parameters) |" in text


def test_a_failed_fit_and_a_crashed_run_are_failed_rows_not_a_dead_table(tmp_path):
    # A failed behaviour-cloning fit: DAgger never starts, so its record (no history) is BC's own.
    record = {"system": "bacteria", "method": "dagger", "demos": 10, "seed": 1, "normalized_score": None,
              "episode_return": None, "status": "non_finite", "seconds": {"demonstrations": 1.0, "bc": 2.0},
              "dagger_history": []}
    row = te.bc_from_dagger(record)
    assert (row["method"], row["status"], row["normalized_score"], row["seconds"]) == ("bc", "non_finite", None, 3.0)

    def crash(system, demos, seed, methods, values, separate_bc=False):
        raise RuntimeError("boom")

    args = te.parse(["--systems", "simple_case", "--demos", "1", "--seeds", "0", "--methods", "bc", "dagger"])
    results = te.Results(str(tmp_path / "t.json"), {})
    results.baseline("simple_case").update(mpc={"score": 99.5, "seconds": 1.0}, ppo={"status": "not installed"},
                                           optimum={"cost": -1.35, "agreement": 0.0, "tolerance": 1e-6})
    te.run_table(args, {}, results, ["bc", "dagger"], runner=crash, progress=False)
    rows = results.data["rows"]
    assert [(r["method"], r["status"], r["message"]) for r in rows] == [("bc", "error", "RuntimeError: boom"),
                                                                         ("dagger", "error", "RuntimeError: boom")]
    assert "failed (1 runs)" in te.markdown(results, ["simple_case"], ["bc", "dagger"], [1], {"simple_case": "S"})
