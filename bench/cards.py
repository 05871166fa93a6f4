"""Record the problem cards' reference results and plots, then re-render the cards (docs/cards/).

The compiler renders cards without JAX (``myriadc card``), so the part that needs the runtime lives here: each system
is solved as the reference table solves it (:func:`myriad.runtime.bench.run_bench`: the published setting, then every
other transcription, the best judged by re-simulation), and its entry in ``docs/cards/results.json`` records the
solutions (costs, defects, status; no timings, so a re-run on another machine changes nothing it should not) with the
fingerprint of the problem's mathematics, and ``docs/cards/img/NAME.png`` plots the published-setting solution. Then
the cards and their index are re-rendered. Other systems' entries are kept, so one system can be refreshed alone.

Usage: python -m bench.cards [NAME ...] [--out docs/cards]     (all 18 systems: about 10 min on 2 cores)
"""

import argparse
import io
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

if not __package__:  # run as a file (`python bench/NAME.py`): run as the module, `python -m bench.NAME`
    os.execv(sys.executable, [sys.executable, "-m", "bench." + os.path.basename(__file__)[:-3], *sys.argv[1:]])

import jax

from myriad.compiler.build import check_file
from myriad.compiler.card import RESULTS_FILE, RESULTS_SCHEMA, build_cards, fingerprint
from myriad.runtime import load
from myriad.runtime.bench import run_bench
from myriad.runtime.plotting import plot_solution
from myriad.runtime.solution import json_number
from myriad.runtime.systems import NAMES

ROOT = Path(__file__).resolve().parent.parent
SETTING = "single shooting, 100 control intervals, Heun, IPOPT"  # runtime.bench.PUBLISHED_SETTING, in words
WARM = "[warm-started from the published-setting solution"  # how run_bench marks a warm-started retry


def _method(sol) -> str:
    intervals = sol.controls.shape[0] - 1
    text = f"{sol.transcription} ({sol.integrator}, {intervals} intervals) + {sol.solver}"
    return text + (", warm-started" if WARM in sol.message else "")


def _record(sol, role: str, best: bool) -> dict:
    return {
        "method": _method(sol), "role": role, "best": best, "converged": bool(sol.converged), "status": str(sol.status),
        "cost": json_number(sol.cost), "max_defect": json_number(sol.max_defect),
        "simulated_cost": json_number(sol.simulated_cost),
        "simulated_max_defect": json_number(max((abs(d) for d in sol.simulated_defect), default=0.0)),
    }


def _small_png(draw, path: Path) -> None:
    """Draw to a PNG, then store it with a 64-colour palette: line plots lose nothing visible and shrink ~3x."""
    from PIL import Image

    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "plot.png"
        draw(raw)
        image = Image.open(raw).convert("RGB").quantize(colors=64, method=Image.Quantize.MEDIANCUT)
        buf = io.BytesIO()
        image.save(buf, format="PNG", optimize=True)
    path.write_bytes(buf.getvalue())


def record(name: str, out: Path) -> dict:
    system = load(name)
    row = run_bench([name], progress=lambda s: print(s, flush=True))[0]
    solutions = [_record(row.main, "published", row.best is row.main)]
    solutions += [_record(s, "alternative", row.best is s) for s in row.alternatives]
    (out / "img").mkdir(parents=True, exist_ok=True)
    _small_png(lambda p: plot_solution(row.main, p, system), out / "img" / f"{name}.png")
    return {"fingerprint": fingerprint(check_file(ROOT / "specs" / f"{name}.yaml")), "setting": SETTING,
            "meets_target": row.meets, "solutions": solutions, "plot": f"img/{name}.png"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("systems", nargs="*", metavar="NAME", help="default: all shipped systems")
    ap.add_argument("--out", default=str(ROOT / "docs" / "cards"), metavar="DIR")
    args = ap.parse_args()
    unknown = sorted(set(args.systems) - set(NAMES))
    if unknown:
        print(f"unknown systems {unknown}; shipped: {', '.join(NAMES)}", file=sys.stderr)
        return 2
    out = Path(args.out).resolve()
    path = out / RESULTS_FILE
    data = json.loads(path.read_text()) if path.is_file() else {}
    if data.get("schema") != RESULTS_SCHEMA:
        data = {"schema": RESULTS_SCHEMA, "systems": {}}
    for name in args.systems or list(NAMES):
        data["systems"][name] = record(name, out)
        # Written after every system, so an interrupted run keeps what it finished.
        data["recorded_with"] = {"command": "python bench/cards.py", "python": platform.python_version(),
                                 "jax": jax.__version__, "machine": platform.machine()}
        out.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    # Rendered from the repository root, so the cards name their specs as `myriadc card specs/ -o docs/cards` does.
    os.chdir(ROOT)
    result = build_cards(["specs"], os.path.relpath(out))
    for w in result.written:
        print(f"wrote {w}")
    return 1 if result.errors else 0


if __name__ == "__main__":
    sys.exit(main())
