"""Problem cards: committed and fresh for every shipped system, deterministic, inert on hostile text, and shown with
results only while the results were computed for the problem as it now stands."""

import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from myriad.compiler.build import check_file
from myriad.compiler.card import RESULTS_FILE, build_cards, card_file, fingerprint, load_results, md, symbol_tex
from myriad.compiler.cli import main

from ..helpers import ALL_SPEC_NAMES, ROOT, SPECS_DIR

CARDS = ROOT / "docs" / "cards"
HOSTILE = sorted((ROOT / "tests" / "compiler" / "hostile_text").glob("*.yaml"))


def test_committed_cards_are_up_to_date(monkeypatch):
    # Run as `make test` runs it (from the root, relative paths), since the cards name their spec by that path.
    monkeypatch.chdir(ROOT)
    result = build_cards([os.path.relpath(SPECS_DIR)], os.path.relpath(CARDS), check=True)
    assert not result.errors
    assert not result.stale, "stale: run `myriadc card specs/ -o docs/cards`\n" + "".join(result.diffs)[:4000]
    assert sorted(p.stem for p in CARDS.glob("*.md") if p.stem != "README") == sorted(ALL_SPEC_NAMES)


@pytest.mark.parametrize("name", ALL_SPEC_NAMES)
def test_every_card_shows_results_recorded_for_its_current_problem(name):
    entry = load_results(CARDS / RESULTS_FILE).get(name)
    assert entry is not None, f"no results for {name}: run `python bench/cards.py {name}`"
    assert entry["fingerprint"] == fingerprint(check_file(SPECS_DIR / f"{name}.yaml")), \
        f"results for {name} are from another version of the problem: run `python bench/cards.py {name}`"
    main_solution = entry["solutions"][0]
    assert main_solution["role"] == "published" and main_solution["converged"] and entry["meets_target"] is True
    assert sum(s["best"] for s in entry["solutions"]) == 1
    plot = CARDS / entry["plot"]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and plot.stat().st_size < 100_000
    card = (CARDS / f"{name}.md").read_text()
    assert f"]({entry['plot']})" in card and f"cost **{main_solution['cost']:.6g}**" in card


def test_check_reports_an_edited_card_and_a_missing_plot(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    spec = os.path.relpath(SPECS_DIR / "simple_case.yaml")
    shutil.copy(CARDS / RESULTS_FILE, tmp_path / RESULTS_FILE)
    (tmp_path / "img").mkdir()
    shutil.copy(CARDS / "img" / "simple_case.png", tmp_path / "img")
    assert main(["card", spec, "-o", str(tmp_path), "-q"]) == 0
    assert main(["card", spec, "-o", str(tmp_path), "--check"]) == 0
    card = tmp_path / "simple_case.md"
    card.write_text(card.read_text().replace("Horizon T = 1;", "Horizon T = 2;"))
    capsys.readouterr()
    assert main(["card", spec, "-o", str(tmp_path), "--check"]) == 1
    out, err = capsys.readouterr()
    assert "-Horizon T = 2;" in out and "+Horizon T = 1;" in out and "stale" in err
    assert main(["card", spec, "-o", str(tmp_path), "-q"]) == 0
    (tmp_path / "img" / "simple_case.png").unlink()
    assert main(["card", spec, "-o", str(tmp_path), "--check"]) == 1
    assert "simple_case.png (missing plot)" in capsys.readouterr().err


def test_results_of_another_version_of_the_problem_are_not_shown(tmp_path):
    text = (SPECS_DIR / "van_der_pol.yaml").read_text()
    results = json.loads((CARDS / RESULTS_FILE).read_text())
    (tmp_path / RESULTS_FILE).write_text(json.dumps(results))
    shown = "Published setting ("
    spec = tmp_path / "van_der_pol.yaml"
    spec.write_text(text.replace("Drive a forced", "Bring a forced"))  # prose: same problem, results still apply
    assert fingerprint(check_file(spec)) == fingerprint(check_file(SPECS_DIR / "van_der_pol.yaml"))
    assert shown in card_file(spec, tmp_path / RESULTS_FILE, tmp_path)
    spec.write_text(text.replace("bounds: [-0.75, 1]", "bounds: [-0.8, 1]"))  # mathematics: a new problem
    card = card_file(spec, tmp_path / RESULTS_FILE, tmp_path)
    assert shown not in card and "computed for another version of this problem" in card
    assert "No reference results are recorded" in card_file(spec, tmp_path / "absent.json", tmp_path)


def test_a_malformed_results_file_is_an_error_not_an_empty_one(tmp_path):
    (tmp_path / RESULTS_FILE).write_text(json.dumps({"schema": 99, "systems": {}}))
    with pytest.raises(ValueError, match="schema"):
        load_results(tmp_path / RESULTS_FILE)


def test_cards_are_byte_identical_across_hash_seeds(tmp_path):
    # sympy's term order must not follow set iteration; tumour and timber_harvest print Piecewise u*, cartpole is big.
    texts = []
    for seed in ("0", "4242"):
        code = ("import sys; from myriad.compiler.card import card_file; "
                "sys.stdout.write(''.join(card_file(f'specs/{n}.yaml') for n in sys.argv[1:]))")
        env = {**os.environ, "PYTHONHASHSEED": seed}
        texts.append(subprocess.run([sys.executable, "-c", code, "tumour", "timber_harvest", "cartpole"], cwd=ROOT,
                                    env=env, capture_output=True, text=True, check=True).stdout)
    assert texts[0] == texts[1] and texts[0].count("# ") >= 3


def test_rendering_a_card_does_not_import_jax():
    code = "import sys; import myriad.compiler.card; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("name, dots, tex", [
    ("x0", 0, "x_{0}"), ("x0", 1, r"\dot{x}_{0}"), ("q1_dot", 0, r"\dot{q}_{1}"), ("q1_dot", 1, r"\ddot{q}_{1}"),
    ("theta_dot", 0, r"\dot{\theta}"), ("xdot", 1, r"\ddot{x}"), ("T_max", 0, r"T_{\mathrm{max}}"),
    ("power", 0, r"\mathit{power}"), ("delta", 0, r"\delta"), ("m_p", 0, "m_{p}"), ("pbar", 0, r"\bar{p}"),
])
def test_symbol_tex(name, dots, tex):
    assert symbol_tex(name, dots) == tex


ALLOWED_TAGS = re.compile(r"<!-- Autogenerated by myriadc card|</?details>|</?summary>")


MARKUP_SPEC = """\
schema: 1
name: markup
title: "<img src=x onerror=alert(1)> | *bold* $x$"
description: "# heading\\n1. list | cell <script>alert(1)</script> [link](http://x) ![img](y) ```fence``` $$ \\\\"
source: "- item\\n> quote\\n<!-- comment -->"
parameters:
  k: {value: 0.5, description: "a | b $c$ <d>", units: "`code` |"}
states:
  x: {initial: 1, bounds: [0, 10], description: "\\n## sub | x", units: "<u>"}
controls:
  u: {bounds: [-1, 1], description: "---|---", units: "&lt;"}
dynamics:
  x: -k*x + u
cost:
  sense: minimize
  running: x**2 + u**2
horizon: 1
reference: {published: 1.5, note: "| note <b> $n$"}
"""


def _assert_inert(card: str) -> None:
    lines = card.splitlines()
    assert lines[0].startswith("<!--") and lines[0].endswith("-->") and lines[0].count("-->") == 1
    assert lines[1].startswith("# ") and lines[2] == ""
    assert not re.search(r"(?<!\\)<", ALLOWED_TAGS.sub("", card)), "raw HTML from the spec"
    outside_math = re.sub(r"```math\n.*?```", "", card, flags=re.S)
    assert [ln for ln in outside_math.splitlines() if ln.startswith("#")] == [lines[1]] + [
        ln for ln in lines if ln.startswith("## ")], "a heading from the spec"
    assert not re.search(r"^(\d+\.|[-+>] )", outside_math, flags=re.M), "a list or quote from the spec"
    symbols_removed = re.sub(r"\| \$[^$|]+\$ \|", "|", outside_math)  # the symbol column: LaTeX of identifiers
    assert not re.search(r"(?<!\\)\$", symbols_removed), "math from the spec"
    for table in re.findall(r"(?:^\|.*\n)+", card, flags=re.M):
        widths = {len(re.findall(r"(?<!\\)\|", row)) for row in table.splitlines()}
        assert len(widths) == 1, f"a cell split by text from the spec:\n{table}"


@pytest.mark.parametrize("path", HOSTILE, ids=[p.stem for p in HOSTILE])
def test_hostile_text_stays_inert_markdown(path, tmp_path):
    _assert_inert(card_file(path, tmp_path / "absent.json", tmp_path))


def test_markup_in_spec_text_stays_text(tmp_path):
    spec = tmp_path / "markup.yaml"
    spec.write_text(MARKUP_SPEC)
    card = card_file(spec, tmp_path / "absent.json", tmp_path)
    _assert_inert(card)
    assert r"\<img src=x onerror=alert(1)\> \| \*bold\* \$x\$" in card.splitlines()[1]
    assert "(`0.5`)" not in card and "| `k` | $k$ | 0.5 |" in card


def test_markdown_escaping():
    assert md("van_der_pol & co") == "van_der_pol & co"  # readable: intraword _ and a bare & are plain text
    assert md("<b>*x*</b> &amp; [a](b) $y$ | _z_") == r"\<b\>\*x\*\</b\> \&amp; \[a\](b) \$y\$ \| \_z\_"
    assert md("# a\nb\u2028c") == r"\# a b c" and md("1. x") == r"1\. x"


def test_cli_usage(capsys):
    assert main(["card", "van_der_pol"]) == 0
    assert capsys.readouterr().out.startswith("<!-- Autogenerated by myriadc card from")
    assert main(["card", str(SPECS_DIR)]) == 2  # several cards: only into a folder
    assert main(["card", "van_der_pol", "--check"]) == 2
    assert main(["card", "no_such_system"]) == 2
