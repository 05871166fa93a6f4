"""README.md's examples are tests: every fenced code block runs here as written, or is checked and skipped with its
reason.

A block's markers are an HTML comment on the line before it (invisible on GitHub and in the docs site), combined
with commas:

- ``<!-- readme-test: slow -->``: it runs under the ``slow`` marker (more than a few seconds of work);
- ``<!-- readme-test: continues -->``: a python block that uses the names of the python block before it (the
  README's running example): it runs after that block, in the same interpreter;
- ``<!-- readme-test: skip (why) -->``: it is not run (minutes of training, an installation, a cluster), and the
  reason is required; every command in it is still checked: a ``myriad`` / ``myriadc`` line is parsed by that
  command's own argument parser (its flags and choices), a ``make`` target must be in the Makefile, a
  ``python -m`` module must exist, and any other program must be on the PATH.

How blocks run: each in a fresh folder laid out like a clone's root (``specs/`` linked), with ``.venv/bin`` first on
the PATH (what ``source .venv/bin/activate`` does) and one cache folder for all blocks (``caches``); a yaml block
whose first line names a file (``# my_oscillator.yaml``) is written there as that file first. sh blocks run with
``bash -e``,
python blocks in a new interpreter (so without the test suite's float64 setting: the examples must set what they
need themselves).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from .helpers import ROOT

README = ROOT / "README.md"
MARKER = re.compile(r"<!--\s*readme-test:\s*(.*?)\s*-->\Z")
FENCE = re.compile(r"```(\w*)\s*\Z")
LANGUAGES = ("sh", "python", "yaml")
FILE_NAME = re.compile(r"#\s*([\w.-]+\.(?:yaml|yml))\s*\Z")
VENV_BIN = Path(sys.executable).parent


@dataclasses.dataclass(frozen=True)
class Block:
    name: str  # the section's heading and the block's place in it: `solving-python-2`
    line: int  # of the opening fence, 1-based
    lang: str
    text: str
    markers: tuple[str, ...] = ()
    reason: str = ""

    @property
    def slow(self) -> bool:
        return "slow" in self.markers

    @property
    def skipped(self) -> bool:
        return "skip" in self.markers


def blocks(text: str) -> list[Block]:
    """Every fenced block of the Markdown text, with the markers of the comment just above it."""
    out, lines, i, section, counts = [], text.splitlines(), 0, "top", {}
    while i < len(lines):
        m = FENCE.match(lines[i].strip())
        if not m or not lines[i].startswith("```"):
            if lines[i].startswith("#"):
                section = re.sub(r"[^a-z0-9]+", "-", lines[i].lstrip("#").strip().lower()).strip("-")
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        above = next((lines[j].strip() for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        marker = MARKER.match(above)
        markers, reason = _markers(marker.group(1)) if marker else ((), "")
        counts[section, m.group(1)] = n = counts.get((section, m.group(1)), 0) + 1
        out.append(Block(f"{section}-{m.group(1)}-{n}", i + 1, m.group(1), "\n".join(lines[i + 1:end]) + "\n",
                         markers, reason))
        i = end + 1
    return out


def _markers(text: str) -> tuple[tuple[str, ...], str]:
    """``skip (why), slow`` -> (("skip", "slow"), "why")."""
    reason = re.search(r"\((.*)\)", text)
    words = re.sub(r"\(.*\)", "", text)
    return tuple(w.strip() for w in words.split(",") if w.strip()), reason.group(1).strip() if reason else ""


ALL = blocks(README.read_text(encoding="utf-8"))
FILES = {FILE_NAME.match(b.text.splitlines()[0]).group(1): b.text for b in ALL
         if b.lang == "yaml" and FILE_NAME.match(b.text.splitlines()[0])}


def _units() -> list[tuple[str, list[Block]]]:
    """The blocks that run, a python block together with the blocks that continue it."""
    units: list[tuple[str, list[Block]]] = []
    for b in ALL:
        if b.skipped or b.lang == "yaml":
            continue
        if "continues" in b.markers:
            units[-1][1].append(b)
        else:
            units.append((b.name, [b]))
    return units


def _params(units):
    return [pytest.param(chain, id=name, marks=[pytest.mark.slow] if any(b.slow for b in chain) else [])
            for name, chain in units]


def test_every_block_is_run_or_checked():
    """Each block has a language this file runs, skips say why, continuations follow a python block."""
    assert len(ALL) >= 15
    previous = None
    for b in ALL:
        where = f"README.md:{b.line}"
        assert b.lang in LANGUAGES, f"{where}: a ```{b.lang} block: this test runs only {LANGUAGES}"
        assert set(b.markers) <= {"slow", "skip", "continues"}, f"{where}: unknown marker in {b.markers}"
        assert not b.skipped or b.reason, f"{where}: `readme-test: skip` needs its reason: `skip (why)`"
        if b.lang == "yaml":
            assert FILE_NAME.match(b.text.splitlines()[0]) or b.skipped, f"{where}: name the file: `# NAME.yaml`"
        if "continues" in b.markers:
            assert b.lang == "python" and previous is not None and previous.lang == "python" \
                and not previous.skipped, f"{where}: `continues` follows a python block that runs"
        if b.lang == "python":
            previous = b
    assert any(b.skipped for b in ALL) and any(not b.skipped for b in ALL if b.lang != "yaml")


def test_markers_are_read():
    text = ("x\n<!-- readme-test: skip (a long run), slow -->\n```sh\nmake demo\n```\n\n```python\nprint(1)\n```\n"
            "<!-- readme-test: continues -->\n\n```python\nprint(2)\n```\n")
    found = blocks(text)
    assert [(b.name, b.line, b.lang, b.markers, b.reason) for b in found] == [
        ("top-sh-1", 3, "sh", ("skip", "slow"), "a long run"), ("top-python-1", 7, "python", (), ""),
        ("top-python-2", 12, "python", ("continues",), "")]
    assert found[1].text == "print(1)\n"


@pytest.fixture
def workdir(tmp_path):
    """A folder laid out like a clone's root: ``specs/`` linked, the README's named files written."""
    (tmp_path / "specs").symlink_to(ROOT / "specs", target_is_directory=True)
    for name, text in FILES.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    return tmp_path


@pytest.fixture(scope="module")
def caches(tmp_path_factory) -> Path:
    """One cache folder for every block, as a reader running the README top to bottom has (~/.cache/myriad): the
    specs compiled by path, the reference scores certified, and JAX's compilation cache, which the `myriad` commands
    turn on by default (the suite's MYRIAD_JAX_CACHE=off is for in-process tests)."""
    return tmp_path_factory.mktemp("myriad-cache")


def _env(caches: Path) -> dict:
    return dict(os.environ, PATH=f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}",
                MYRIAD_CACHE=str(caches), MYRIAD_JAX_CACHE=str(caches / "jax"), PYTHONDONTWRITEBYTECODE="1")


@pytest.mark.parametrize("chain", _params(_units()))
def test_block_runs_as_written(chain: list[Block], workdir, caches):
    first = chain[0]
    if first.lang == "python":
        (workdir / "example.py").write_text("".join(b.text for b in chain), encoding="utf-8")
        argv = [sys.executable, "example.py"]
    else:
        argv = ["bash", "-e", "-c", first.text]
    run = subprocess.run(argv, cwd=workdir, env=_env(caches), capture_output=True, text=True,
                         timeout=900 if first.slow else 180)
    assert run.returncode == 0, f"README.md:{first.line} ({first.lang}) failed:\n{run.stdout}\n{run.stderr}"
    for text in (run.stdout, run.stderr):
        assert "internal error" not in text and "Traceback" not in text, text


# -- skipped blocks: their commands are checked ------------------------------------------------------------------


def _commands(text: str) -> list[list[str]]:
    """The commands of an sh block, without comments."""
    return [shlex.split(line, comments=True) for line in text.splitlines() if shlex.split(line, comments=True)]


def _parse(program: str, argv: list[str]) -> None:
    """Parse ``argv`` with the command's own parser (flags, choices, positionals); nothing runs."""
    if program == "myriadc":
        from myriad.compiler.cli import _parser
    else:
        from myriad.runtime.cli import _parser
    try:
        _parser().parse_args(argv)
    except SystemExit as exc:
        raise AssertionError(f"`{program} {shlex.join(argv)}` is not a valid command line") from exc


def _make_targets() -> set[str]:
    return set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(encoding="utf-8"), re.MULTILINE))


def _check_command(words: list[str]) -> None:
    program, args = words[0], words[1:]
    if program in ("myriad", "myriadc"):
        _parse(program, args)
    elif program == "make":
        assert set(args) <= _make_targets(), f"`make {' '.join(args)}`: not a target of the Makefile"
    elif program in ("python", "python3") and args[:1] == ["-m"]:
        assert importlib.util.find_spec(args[1]) is not None or (ROOT / args[1].replace(".", "/")).with_suffix(
            ".py").is_file(), f"`python -m {args[1]}`: no such module"
    else:
        path = f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}"
        assert shutil.which(program, path=path), f"`{program}`: not on the PATH (with .venv/bin first)"


SKIPPED = [b for b in ALL if b.skipped and b.lang == "sh"]


@pytest.mark.parametrize("block", SKIPPED, ids=[b.name for b in SKIPPED])
def test_skipped_block_commands_exist(block: Block, capsys):
    commands = _commands(block.text)
    assert commands, f"README.md:{block.line}: no command in a skipped block"
    for words in commands:
        _check_command(words)
    capsys.readouterr()
