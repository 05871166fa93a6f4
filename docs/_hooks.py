"""MkDocs hooks for the myriad site (``mkdocs.yml``: ``hooks``): where the API reference finds ``myriad``, sections of
the repository's READMEs included in pages, and links that leave ``docs/``.

- The distribution maps ``myriad.runtime`` onto ``runtime/`` and ``myriad.compiler`` onto ``compiler/``
  (``pyproject.toml``: ``package-dir``). griffe, which reads the docstrings without importing anything, looks for a
  folder named ``myriad`` on its search path and does not follow that mapping, so the build gets one: a temporary
  folder whose ``myriad/`` package holds symlinks to the two source folders.
- A page line ``--8<-- "README.md:solving"`` is replaced by the lines of ``README.md`` between the markers
  ``--8<-- [start:solving]`` and ``--8<-- [end:solving]`` (HTML comments there; ``--8<-- "specs/README.md"``: the
  whole file), so the guide and the README say the same thing from one text. A missing file or section fails the
  build.
- Docstrings are Google style with reST's ``.. math::`` blocks and ``:class:`` / ``:func:`` / ``:meth:`` / ``:mod:``
  roles. A Markdown preprocessor (added to every page and to mkdocstrings' rendering) turns the blocks into
  arithmatex's ``\\[ ... \\]`` (typeset by MathJax) and the roles into code spans.
- Links are written for GitHub, relative to the file they are in. One into ``docs/``, or to a file that a page
  includes whole (a folder's README), is rewritten to that page. Any other file outside ``docs/`` (a spec, a module)
  has no copy in the site, and ``--strict`` fails on a link it cannot resolve, so such a link becomes the repository
  path in code. A broken link inside the site still fails.
"""

from __future__ import annotations

import atexit
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

from markdown import Extension
from markdown.preprocessors import Preprocessor
from mkdocs.exceptions import PluginError

ROOT = Path(__file__).resolve().parents[1]
_LINK = re.compile(r"(?<!!)\[([^\]\n]+)\]\(([^)\s]+)\)")
_INCLUDE = re.compile(r'^--8<-- "([^":]+)(?::([\w-]+))?"[ \t]*$', re.MULTILINE)


def _source_folder() -> Path:
    src = Path(tempfile.mkdtemp(prefix="myriad-docs-src-"))
    atexit.register(shutil.rmtree, src, ignore_errors=True)
    (src / "myriad").mkdir()
    # A regular package, not a namespace: griffe prefers any module named `myriad` to a namespace folder, and the
    # console script .venv/bin/myriad is one.
    (src / "myriad" / "__init__.py").write_text('"""myriad: a declarative optimal-control testbed."""\n')
    for name in ("runtime", "compiler"):
        (src / "myriad" / name).symlink_to(ROOT / name, target_is_directory=True)
    return src


_MATH = re.compile(r"^(\s*)\.\. math::\s*(.*)$")
_ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|obj|exc):`(~?)\.*([^`]+)`")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


class _RestMath(Preprocessor):
    """``.. math::`` and its indented body (or the rest of its line) -> a ``\\[ ... \\]`` block; a role -> code."""

    def run(self, lines):
        out, i = [], 0
        while i < len(lines):
            math = _MATH.match(lines[i])
            if not math:
                out.append(_ROLE.sub(lambda m: f"`{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}`",
                                     lines[i]))
                i += 1
                continue
            indent, body = math.group(1), [math.group(2)] if math.group(2) else []
            i += 1
            while i < len(lines) and (not lines[i].strip() or _indent(lines[i]) > len(indent)):
                body.append(lines[i].strip())
                i += 1
            out += ["", indent + "\\[", *(indent + b for b in body if b), indent + "\\]", ""]
        return out


class _RestMathExtension(Extension):
    def extendMarkdown(self, md):  # noqa: N802 (Markdown's name)
        md.preprocessors.register(_RestMath(md), "myriad-rest-math", 35)  # before arithmatex and code blocks


def on_config(config):
    # After mkdocstrings' on_config, which handed this same list to its handlers: their Markdown is built later.
    config.markdown_extensions.append(_RestMathExtension())
    return config


def on_startup(command, dirty):
    # Not in on_config: mkdocstrings creates its python handler, which copies sys.path, in its own on_config, and
    # hooks run after plugins (and MkDocs restores sys.path after importing this file).
    sys.path.insert(0, str(_source_folder()))


def _section(path: Path, name: str | None) -> str:
    """The lines of ``path`` between its start and end markers for ``name`` (all of it without ``name``), the marker
    lines themselves left out."""
    if not path.is_file():
        raise PluginError(f"--8<--: no file {path}")
    lines = path.read_text(encoding="utf-8").splitlines()
    if name:
        tags = (f"--8<-- [start:{name}]", f"--8<-- [end:{name}]")
        marks = [i for i, line in enumerate(lines) if any(tag in line for tag in tags)]
        if len(marks) != 2:
            raise PluginError(f"--8<--: {path} has no section {name!r} (one start and one end marker)")
        lines = lines[marks[0] + 1 : marks[1]]
    return "\n".join(line for line in lines if "--8<-- [" not in line) + "\n"


# A file that a page includes whole (e.g. runtime/sysid/README.md) -> that page: links to the file go there.
_INCLUDED: dict[Path, Path] = {}


def on_files(files, config):
    _INCLUDED.clear()
    for page in files.documentation_pages():
        for match in _INCLUDE.finditer(Path(page.abs_src_path).read_text(encoding="utf-8")):
            if not match.group(2):
                _INCLUDED[(ROOT / match.group(1)).resolve()] = Path(page.abs_src_path).resolve()
    return files


def _relink(markdown: str, base: Path, page_dir: Path, docs: Path) -> str:
    """The relative links of ``markdown`` (written relative to ``base``) for a page in ``page_dir``."""

    def link(match):
        text, target = match.group(1), match.group(2)
        if re.match(r"^[a-z]+:|^#|^/", target):
            return match.group(0)
        file, _, anchor = target.partition("#")
        path = (base / file).resolve()
        path = _INCLUDED.get(path, path)
        if path == docs or docs in path.parents:
            rel = os.path.relpath(path, page_dir).replace(os.sep, "/")
            return f"[{text}]({rel}{'#' + anchor if anchor else ''})"
        try:
            shown = path.relative_to(ROOT).as_posix()
        except ValueError:
            shown = target
        named = text.strip("`").rstrip("/")
        return text if named and shown.startswith(named) else f"{text} (`{shown}`)"  # the text already names it

    return _LINK.sub(link, markdown)


def on_page_markdown(markdown, page, config, files):
    docs = Path(config["docs_dir"]).resolve()
    here = Path(page.file.abs_src_path).parent
    # _INCLUDE has two groups: split gives [text, file, section, text, file, section, ..., text].
    parts = _INCLUDE.split(markdown)
    out = [_relink(parts[0], here, here, docs)]
    for k in range(1, len(parts), 3):
        path = (ROOT / parts[k]).resolve()
        out.append(_relink(_section(path, parts[k + 1]), path.parent, here, docs))
        out.append(_relink(parts[k + 2], here, here, docs))
    return "".join(out)
