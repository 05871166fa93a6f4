"""Arguments and checks shared by the commands that learn (`myriad sysid`, `myriad e2e`) and write tables
(`myriad sweep`): the same options spelled the same way, refused with the same words before any work."""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["add_training_outputs", "first_error", "usage"]


def add_training_outputs(parser, plots_help: str) -> None:
    """``--json FILE``, ``--plots DIR``, ``--checkpoint DIR`` and ``--resume``."""
    parser.add_argument("--json", metavar="FILE", help="write the record as JSON")
    parser.add_argument("--plots", metavar="DIR", help=plots_help)
    parser.add_argument("--checkpoint", metavar="DIR", help="write checkpoints here")
    parser.add_argument("--resume", action="store_true", help="continue from the last checkpoint in --checkpoint")


def first_error(args, files=("json",)) -> str | None:
    """The first usage error of the shared options: ``--resume`` without ``--checkpoint``, an output file whose
    folder does not exist (``files`` names the attributes holding output paths)."""
    if getattr(args, "resume", False) and not getattr(args, "checkpoint", None):
        return "--resume needs --checkpoint DIR"
    for path in (getattr(args, name, None) for name in files):
        if path and not Path(path).resolve().parent.is_dir():
            return f"the folder of {path} does not exist"
    return None


def usage(command: str, message: str) -> int:
    """Print ``myriad COMMAND: error: MESSAGE`` to stderr; the exit code of a usage error (2)."""
    print(f"myriad {command}: error: {message}", file=sys.stderr)
    return 2
