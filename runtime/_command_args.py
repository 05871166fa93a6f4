"""Arguments and checks shared by the commands that learn (`myriad sysid`, `myriad e2e`) and write tables
(`myriad sweep`): the same options spelled the same way, refused with the same words before any work."""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["add_training_outputs", "first_error", "output_file_error", "output_folder_error", "plot_format_error",
           "usage"]


def add_training_outputs(parser, plots_help: str) -> None:
    """``--json FILE``, ``--plots DIR``, ``--checkpoint DIR`` and ``--resume``."""
    parser.add_argument("--json", metavar="FILE", help="write the record as JSON")
    parser.add_argument("--plots", metavar="DIR", help=plots_help)
    parser.add_argument("--checkpoint", metavar="DIR", help="write checkpoints here")
    parser.add_argument("--resume", action="store_true", help="continue from the last checkpoint in --checkpoint")


def first_error(args, files=("json",)) -> str | None:
    """The first usage error of the shared options: ``--resume`` without ``--checkpoint``, an output folder that
    cannot be made, an output file whose folder does not exist (``files`` names the attributes holding their paths)."""
    if getattr(args, "resume", False) and not getattr(args, "checkpoint", None):
        return "--resume needs --checkpoint DIR"
    for name in ("plots", "checkpoint"):
        if error := output_folder_error(getattr(args, name, None), f"--{name}"):
            return error
    for name in files:
        path = getattr(args, name, None)
        if path and not Path(path).resolve().parent.is_dir():
            return f"--{name} {path}: the folder of {path} does not exist; create it first"
    return None


def usage(command: str, message: str) -> int:
    """Print ``myriad COMMAND: error: MESSAGE`` to stderr; the exit code of a usage error (2)."""
    print(f"myriad {command}: error: {message}", file=sys.stderr)
    return 2


def output_file_error(path, option):
    """Why ``path`` cannot be written as a file (None if it can): checked before the work that would fill it."""
    if path is None:
        return None
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        return f"{option} {path}: is a folder, expected a file name"
    if not os.path.isdir(folder):
        what = "is not a folder" if os.path.exists(folder) else "does not exist"
        return f"{option} {path}: the folder {folder} {what}; create it first"
    if not os.access(folder, os.W_OK | os.X_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        return f"{option} {path}: not writable"
    return None


def output_folder_error(path, option):
    """Why ``path`` cannot be used as an output folder (None if it can); missing folders are created later."""
    if path is None:
        return None
    existing = os.path.abspath(path)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        return f"{option} {path}: {existing} is a file, not a folder"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"{option} {path}: {existing} is not writable"
    return None


def plot_format_error(path, option):
    if path is None:
        return None
    from matplotlib.backend_bases import FigureCanvasBase

    ext = os.path.splitext(path)[1].lstrip(".").lower()
    formats = FigureCanvasBase.get_supported_filetypes()
    if ext and ext not in formats:
        return f"{option} {path}: unknown image format .{ext}; use one of {', '.join(sorted(formats))}"
    return None
