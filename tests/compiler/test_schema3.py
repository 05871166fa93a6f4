"""Schema 3 (uncertainty): what the compiler generates for it, and what it leaves alone.

The example specs in ``schema3/`` compile, load and round-trip: the generated attributes (the interface of issue 30,
declared with their defaults in runtime/system.py) equal what the YAML says. Earlier schemas' modules, cards and
`show` output gain nothing; a schema 2 problem restated as schema 3 is the same problem. The CasADi export carries the
same data, and its scenario problem is checked against closed forms of the mean, worst case and CVaR. Bad schema 3
specs are in ``bad_specs/`` (``s3_*``), checked by ``test_bad_specs.py``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from myriad.compiler import SpecErrors, compile_file, compile_spec
from myriad.compiler.errors import flatten
from myriad.runtime import load
from myriad.runtime.system import System

from ..helpers import ALL_SPECS, ROOT

HERE = Path(__file__).resolve().parent / "schema3"
EXAMPLES = sorted(HERE.glob("*.yaml"))
ATTRIBUTES = ("uncertain_params", "uncertain_kinds", "uncertain_args", "scenarios", "robust_objective", "robust_alpha",
              "robust_samples", "robust_seed", "process_noise", "observation_noise")
EARLIER = [p for p in (*ALL_SPECS, *sorted((ROOT / "specs" / "peers").glob("*.yaml")),
                        *sorted((HERE.parent / "schema2").glob("*.yaml")))
           if not p.read_text(encoding="utf-8").startswith("schema: 3")]  # shipped specs that declare uncertainty


@pytest.fixture(scope="module")
def systems(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MYRIAD_CACHE", str(cache))
        return {p.stem: load(p) for p in EXAMPLES}


def _expected(doc: dict) -> dict:
    """The schema 3 attributes as the YAML states them, read independently of the compiler."""
    params = doc.get("parameters", {})
    uncertain = [(name, p["uncertain"]) for name, p in params.items() if isinstance(p, dict) and "uncertain" in p]
    names = [name for name, _ in uncertain]
    robust = doc.get("robust")
    objective = robust["objective"] if robust else None
    noise = doc.get("noise", {})

    def per_state(part):
        return () if part not in noise else tuple(float(noise[part].get(s, 0.0)) for s in doc["states"])

    return {
        "uncertain_params": tuple(names),
        "uncertain_kinds": tuple(next(iter(d)) for _, d in uncertain),
        "uncertain_args": tuple(tuple(float(a) for a in next(iter(d.values()))) for _, d in uncertain),
        "scenarios": tuple(tuple(float(s[n]) for n in names) for s in doc.get("scenarios", ())),
        "robust_objective": None if robust is None else ("cvar" if isinstance(objective, dict) else objective),
        "robust_alpha": objective["cvar"] if isinstance(objective, dict) else None,
        "robust_samples": (robust or {}).get("samples", 16),
        "robust_seed": (robust or {}).get("seed", 0),
        "process_noise": per_state("process"),
        "observation_noise": per_state("observation"),
    }


def test_examples_exist():
    assert {p.stem for p in EXAMPLES} >= {"uncertain_oscillator", "drawn_cvar"}


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_generated_attributes_equal_the_yaml(path, systems):
    system = systems[path.stem]
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    assert system.schema == 3
    assert {a: getattr(system, a) for a in ATTRIBUTES} == _expected(doc)
    assert system.uncertain  # every example declares something to plan for
    assert type(system).__dict__.keys() >= set(ATTRIBUTES)  # written into the module, not inherited


def test_the_oscillator_example_as_the_runtime_reads_it(systems):
    s = systems["uncertain_oscillator"]
    assert s.uncertain_params == ("k", "c") and s.uncertain_kinds == ("uniform", "normal")
    assert s.uncertain_args == ((1.5, 2.5), (0.5, 0.05))
    assert s.scenarios == ((1.5, 0.45), (2.0, 0.5), (2.5, 0.55))
    assert s.robust_objective == "mean" and s.robust_alpha is None
    assert s.process_noise == (0.0, 0.05) and s.observation_noise == (0.01, 0.02)
    d = systems["drawn_cvar"]
    assert d.scenarios == () and d.robust_objective == "cvar" and d.robust_alpha == 0.8
    assert (d.robust_samples, d.robust_seed) == (64, 7) and d.process_noise == () and d.observation_noise == ()


def test_defaults_and_the_uncertain_property():
    assert {a: getattr(System, a) for a in ATTRIBUTES} == _expected({"states": {}})
    vdp = load("epidemic")  # a schema 1 system inherits the defaults
    assert not vdp.uncertain and vdp.scenarios == () and vdp.robust_objective is None
    base = (HERE / "uncertain_oscillator.yaml").read_text(encoding="utf-8")
    head, _, _ = base.partition("scenarios:")
    plain = head.replace(", uncertain: {uniform: [1.5, 2.5]}", "").replace(", uncertain: {normal: [0.5, 0.05]}", "")
    variants = {  # the text after the parameters -> whether a robust solve is asked for
        plain + "noise: {process: {v: 0.1}}\n": False,  # noise alone is a stochastic system, not a robust plan
        head: True,  # uncertain parameters alone
        head + "robust: {objective: worst, samples: 4}\n": True,
    }
    for text, uncertain in variants.items():
        c = compile_spec(text, "uncertain_oscillator.yaml")
        attrs = {k: eval(v, {}) for k, v in c.data.metadata if k in ATTRIBUTES}  # our own printed literals
        assert type("Declared", (System,), attrs)().uncertain == uncertain, text


@pytest.mark.parametrize("path", EARLIER, ids=[p.stem for p in EARLIER])
def test_earlier_schemas_gain_nothing(path):
    """Schema 1 and 2 modules, cards and `show` mention no schema 3 field (the committed modules' bytes are checked
    by test_build.py)."""
    from myriad.compiler.card_schema3 import show_lines, uncertainty_blocks

    c = compile_file(path)
    assert c.symbolic.spec.schema < 3
    assert not any(a in c.text for a in ATTRIBUTES if a != "scenarios") and "scenarios =" not in c.text
    assert uncertainty_blocks(c.symbolic) == [] and show_lines(c.symbolic) == []


def test_schema2_problem_restated_as_schema3_is_the_same_problem():
    src = (HERE.parent / "schema2" / "keep_out_zone.yaml").read_text(encoding="utf-8")
    two, three = compile_spec(src, "keep_out_zone.yaml"), compile_spec(src.replace("schema: 2", "schema: 3"),
                                                                     "keep_out_zone.yaml")
    assert two.data.functions == three.data.functions
    extra = dict(three.data.metadata).keys() - dict(two.data.metadata).keys()
    assert extra == set(ATTRIBUTES)
    for attr in extra:
        assert eval(dict(three.data.metadata)[attr], {}) == getattr(System, attr), attr  # our own printed literal
    from myriad.compiler.card_schema3 import show_lines, uncertainty_blocks

    assert uncertainty_blocks(three.symbolic) == ["Nothing is declared uncertain and there is no noise."]
    assert show_lines(three.symbolic) == ["  nothing is declared uncertain, no noise"]


def test_every_schema3_error_is_reported_in_one_run():
    text = (HERE / "uncertain_oscillator.yaml").read_text(encoding="utf-8")
    edits = (("[1.5, 2.5]", "[2.5, 1.5]"), ("[0.5, 0.05]", "[0.5, -1]"), ("{k: 2.0, c: 0.5}", "{k: 2.0}"),
             ("robust: {objective: mean}", "robust: {objective: {cvar: 2}}"), ("{v: 0.05}", "{v: -0.05, y: 1}"))
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    with pytest.raises(SpecErrors) as info:
        compile_spec(text, "uncertain_oscillator.yaml")
    fields = [".".join(e.loc.path) for e in flatten(info.value)]
    assert fields == ["parameters.k.uncertain.uniform", "parameters.c.uncertain.normal.1", "scenarios.2",
                      "robust.objective.cvar", "noise.process.v", "noise.process.y"], fields


def test_card_and_show_render_the_uncertainty(capsys):
    from myriad.compiler.card import card_file, fingerprint
    from myriad.compiler.cli import main

    path = HERE / "uncertain_oscillator.yaml"
    card = card_file(path, results_path=None)
    assert "## Uncertainty" in card
    assert "| `k` | 2 | uniform on [1.5, 2.5] | [0, inf] |" in card
    assert "| `c` | 0.5 | normal, mean 0.5, std 0.05 |   |" in card
    assert "| 3 | 2.5 | 0.55 |" in card
    assert "Robust objective: the mean of the scenario costs, over the 3 explicit scenarios." in card
    assert "| `v` | 0.05 | 0.02 |" in card
    assert "CVaR at alpha = 0.8" in card_file(HERE / "drawn_cvar.yaml", results_path=None)
    # The fingerprint keys the recorded (nominal) results: declaring uncertainty does not invalidate them.
    text = path.read_text(encoding="utf-8")
    nominal = compile_spec(text.partition("scenarios:")[0].replace(", uncertain: {uniform: [1.5, 2.5]}", "")
                           .replace(", uncertain: {normal: [0.5, 0.05]}", ""), path.name)
    assert fingerprint(nominal.symbolic) == fingerprint(compile_file(path).symbolic)
    assert main(["show", str(path)]) == 0
    out = capsys.readouterr().out
    assert "    k          2        uniform on [1.5, 2.5]" in out
    assert "    2         2    0.5" in out and "    v      0.05           0.02" in out


# -- the CasADi export: the same data, and the scenario problem against closed forms ---------------------------------

ADDITIVE = """\
schema: 3
name: additive
title: Additive uncertainty
description: A cost offset c that no control can change, so every objective of the scenario costs has a closed form.
parameters:
  c: {value: 1.0, uncertain: {choice: [0.0, 1.0, 3.0]}}
states:
  x: {initial: 1}
controls:
  u: {bounds: [-1, 1]}
dynamics:
  x: -x + u
cost:
  sense: minimize
  running: x**2 + u**2 + c
horizon: 2
scenarios: [{c: 0.0}, {c: 1.0}, {c: 3.0}]
"""


def test_casadi_export_carries_the_uncertainty(systems):
    pytest.importorskip("casadi")
    from myriad.compiler.casadi_export import export_file

    for path in EXAMPLES:
        cs, system = export_file(path), systems[path.stem]
        assert {a: getattr(cs, a) for a in ATTRIBUTES} == {a: getattr(system, a) for a in ATTRIBUTES}
    cs = export_file(HERE / "uncertain_oscillator.yaml")
    assert cs.scenario_params() == [[1.5, 0.45, 0.1], [2.0, 0.5, 0.1], [2.5, 0.55, 0.1]]
    assert cs.scenario_params([(2.2, 0.4)]) == [[2.2, 0.4, 0.1]]
    with pytest.raises(ValueError, match="one value per uncertain parameter"):
        cs.scenario_params([(2.2,)])
    assert export_file(ALL_SPECS[0]).scenarios == ()


@pytest.mark.slow  # five IPOPT solves of a 3-scenario NLP (a few seconds)
def test_scenario_problem_objectives_match_closed_forms(tmp_path):
    """J_s = J0 + T c_s with the same optimal control for every c: mean, worst and CVaR of {0, 1, 3} (each 1/3) are
    J0 + 2 (4/3), J0 + 2 (3) and, at alpha = 1/2, J0 + 2 (3 (1/3) + 1 (1/6)) / (1/2) = J0 + 2 (7/3)."""
    pytest.importorskip("casadi")
    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import scenario_trapezoidal, trapezoidal

    path = tmp_path / "additive.yaml"
    path.write_text(ADDITIVE, encoding="utf-8")
    cs, N = export_file(path), 40
    nominal = trapezoidal(cs, N, params={"c": 0.0})
    J0 = float(nominal.opti.solve().value(nominal.J))
    for objective, alpha, offset in (("mean", None, 4 / 3), ("worst", None, 3.0), ("cvar", 0.5, 7 / 3)):
        problem = scenario_trapezoidal(cs, N, objective=objective, alpha=alpha)
        sol = problem.opti.solve()
        assert float(sol.value(problem.J)) == pytest.approx(J0 + 2 * offset, abs=1e-7), objective
        assert [float(sol.value(J)) for J in problem.costs] == pytest.approx([J0, J0 + 2, J0 + 6], abs=1e-7)
    # One scenario at the nominal values is the nominal problem.
    single = scenario_trapezoidal(cs, N, rows=[(1.0,)])
    one = trapezoidal(cs, N)
    assert float(single.opti.solve().value(single.J)) == pytest.approx(float(one.opti.solve().value(one.J)), abs=1e-9)


def test_scenario_problem_refuses_what_it_cannot_pose(tmp_path):
    pytest.importorskip("casadi")
    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import scenario_trapezoidal

    with pytest.raises(ValueError, match="no scenarios"):
        scenario_trapezoidal(export_file(HERE / "drawn_cvar.yaml"), 4)
    path = tmp_path / "additive.yaml"
    path.write_text(ADDITIVE, encoding="utf-8")
    with pytest.raises(ValueError, match="0 < alpha < 1"):
        scenario_trapezoidal(export_file(path), 4, objective="cvar", alpha=1.0)
