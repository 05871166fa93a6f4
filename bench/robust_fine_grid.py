"""A robust plan's cost from the command line against an independent fine-grid solve of the same scenario problem.

For each schema 3 spec with explicit scenarios (and each objective asked for): `myriad solve SPEC --transcription
hermite_simpson --json F` (the record's `cost` is the robust objective), then CasADi + IPOPT on the scenario problem
transcribed by trapezoidal collocation at two fine grids (compiler/casadi_opti.scenario_trapezoidal: CasADi's own
derivatives, another transcription, another code path). Prints the gap to the finer grid, and the two fine grids'
own difference as the reference's error bar.

    python -m bench.robust_fine_grid                          # the schema 3 example, objectives mean and worst
    python -m bench.robust_fine_grid SPEC.yaml --objectives mean worst cvar
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[1] / "tests" / "compiler" / "schema3" / "uncertain_oscillator.yaml"


def with_objective(spec: Path, objective: str, folder: Path) -> Path:
    """A copy of ``spec`` whose `robust:` line asks for ``objective`` (cvar at alpha 0.5)."""
    text = spec.read_text()
    wanted = "{cvar: 0.5}" if objective == "cvar" else objective
    text, count = re.subn(r"^robust:.*$", f"robust: {{objective: {wanted}}}", text, flags=re.M)
    if count != 1:
        raise SystemExit(f"{spec}: expected one `robust:` line to rewrite, found {count}")
    path = folder / f"{spec.stem}_{objective}.yaml"
    path.write_text(re.sub(r"^name:.*$", f"name: {path.stem}", text, count=1, flags=re.M))  # the name is the stem
    return path


def command_cost(spec: Path) -> dict:
    out = spec.with_suffix(".json")
    run = subprocess.run([sys.executable, "-m", "myriad.runtime.cli", "solve", str(spec), "--transcription",
                          "hermite_simpson", "--json", str(out)], capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"myriad solve {spec} exited {run.returncode}: {run.stderr.strip()[-400:]}")
    record = json.loads(out.read_text())
    return record[0] if isinstance(record, list) else record


def fine_costs(spec: Path, grids: tuple[int, ...]) -> dict[int, float]:
    from myriad.compiler.casadi_export import export_file
    from myriad.compiler.casadi_opti import scenario_trapezoidal

    cs = export_file(str(spec))
    costs = {}
    for n in grids:
        problem = scenario_trapezoidal(cs, n)
        costs[n] = float(problem.opti.solve().value(problem.J))
    return costs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("specs", nargs="*", type=Path, default=[EXAMPLE])
    parser.add_argument("--objectives", nargs="+", default=["mean", "worst"], choices=["mean", "worst", "cvar"])
    parser.add_argument("--grids", nargs=2, type=int, default=[1000, 2000], metavar=("N1", "N2"))
    args = parser.parse_args(argv)
    worst_gap = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for spec in args.specs:
            for objective in args.objectives:
                copy = with_objective(spec, objective, Path(tmp))
                record, fine = command_cost(copy), fine_costs(copy, tuple(args.grids))
                n1, n2 = args.grids
                gap = abs(record["cost"] - fine[n2])
                worst_gap = max(worst_gap, gap)
                print(f"{spec.name} {objective:5s}: myriad HS({record.get('intervals')}) {record['cost']:.9f}   "
                      f"CasADi trapezoidal N={n1} {fine[n1]:.9f}, N={n2} {fine[n2]:.9f}   gap {gap:.2e}   "
                      f"(fine grids differ by {abs(fine[n1] - fine[n2]):.1e})")
    print(f"largest gap to the finer grid: {worst_gap:.2e} (goal 1e-3)")
    return 0 if worst_gap <= 1e-3 else 1


if __name__ == "__main__":
    sys.exit(main())
