"""The peer collection (specs/peers/): every spec compiles to its committed module, loads as ``peers/<name>``, and the
fast problems reach their published optima to 1e-3 (schema 1 with myriad; schema 2 through the independent CasADi
path, since those are the semantics myriad's transcriptions are being made to enforce). The slow and stiff rows are
in ``bench/peer_table.py``."""

import math

import pytest

from myriad.compiler import render
from myriad.compiler.build import compile_file
from myriad.runtime import load, solve
from myriad.runtime.systems import peers
from myriad.runtime.transcriptions import HermiteSimpson, Trapezoidal

from ..helpers import ROOT

SPECS = sorted((ROOT / "specs" / "peers").glob("*.yaml"))
OUT = ROOT / "runtime" / "systems" / "peers"
RTOL = 1e-3


def _rel(value, published):
    return abs(value - published) / abs(published)


def test_the_collection_is_large_enough_and_uses_the_schema_2_fields():
    systems = [load(f"peers/{p.stem}") for p in SPECS]
    assert len(systems) >= 12
    assert sum(s.free_horizon for s in systems) >= 4
    kinds = {k for s in systems for k in s.path_constraint_kinds}
    assert {"state", "mixed", "control"} <= kinds


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_spec_compiles_to_the_committed_module_and_states_its_optimum(path):
    compiled = compile_file(path, f"specs/peers/{path.name}")
    committed = OUT / f"{compiled.name}.py"
    assert committed.exists() and compiled.text == committed.read_text(encoding="utf-8"), (
        f"{committed} is stale: run `myriadc build specs/peers -o runtime/systems/peers`")
    system = load(f"peers/{path.stem}")
    assert system.name == path.stem
    assert system.source, "a peer problem names its source (collection and problem number)"
    assert math.isfinite(system.reference["published"])
    assert system.reference.get("note", "").startswith("compared: "), "say which quantity is compared"


def test_registry_lists_exactly_the_peer_specs():
    assert peers.NAMES == tuple(sorted(p.stem for p in SPECS))
    assert (OUT / "__init__.py").read_text(encoding="utf-8") == render.render_registry(list(peers.NAMES))


def test_loader_keeps_shipped_names_and_paths_and_refuses_unknown_peers():
    assert load("van_der_pol").name == "van_der_pol"
    assert load(SPECS[0]).name == SPECS[0].stem  # by path: compiled into the cache, as before
    with pytest.raises(KeyError, match="peer collection: alp_rider"):
        load("peers/no_such_problem")
    with pytest.raises(KeyError, match="peers/NAME"):
        load("no_such_system")


# Schema 1, with myriad: the two fastest (seconds each, compilation included). The rest are bench rows.
@pytest.mark.parametrize("name,method", [
    ("hager", HermiteSimpson(intervals=20)),
    ("catalyst_mixing", Trapezoidal(intervals=400)),
], ids=["hager", "catalyst_mixing"])
def test_schema1_peer_reaches_its_published_optimum_with_myriad(name, method):
    system = load(f"peers/{name}")
    sol = solve(system, method)
    published = system.reference["published"]
    assert sol.converged, sol.message
    assert _rel(sol.cost, published) <= RTOL, (sol.cost, published)
    assert _rel(sol.simulated_cost, published) <= RTOL, (sol.simulated_cost, published)


# Schema 2, through casadi.Opti (trapezoidal, path constraints at every node, T a variable).
FAST_SCHEMA2 = [("min_time_double_integrator", 200), ("bryson_denham", 200), ("rayleigh_mixed", 400),
                ("particle_steering", 200), ("brachistochrone", 200), ("goddard_rocket", 400), ("robot_arm", 200),
                ("free_flying_robot", 400)]


@pytest.mark.slow
@pytest.mark.parametrize("name,intervals", FAST_SCHEMA2, ids=[n for n, _ in FAST_SCHEMA2])
def test_schema2_peer_reaches_its_published_optimum_through_casadi(name, intervals):
    pytest.importorskip("casadi")
    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import trapezoidal

    cs = export_file(ROOT / "specs" / "peers" / f"{name}.yaml")
    problem = trapezoidal(cs, intervals)
    sol = problem.opti.solve()  # raises when IPOPT does not converge
    published = load(f"peers/{name}").reference["published"]
    assert _rel(float(sol.value(problem.J)), published) <= RTOL, (float(sol.value(problem.J)), published)
    if cs.free_horizon:
        lo, hi = cs.horizon_bounds
        assert lo < float(sol.value(problem.T)) < hi  # an interior optimum, not a bound the guess ran into
    if cs.n_path:
        g = sol.value(problem.G).reshape(cs.n_path, -1)
        for i, (lo, hi) in enumerate(zip(cs.path_lower, cs.path_upper)):
            assert g[i].min() >= lo - 1e-7 and g[i].max() <= hi + 1e-7, cs.path_names[i]
