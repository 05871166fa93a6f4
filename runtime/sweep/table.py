"""The records of a sweep as one table: Markdown (printed), CSV (every field) and JSON (every record, nested), each
written atomically; the formats: the README's "Records".
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any, Sequence

from ..atomic import atomic_write_text
from .kinds import KINDS

__all__ = ["columns", "csv_text", "json_text", "markdown", "write_tables"]

FORMAT, VERSION = "myriad.sweep", 1
LEADING = ("system", "method", "seed", "status")


def columns(records: Sequence[dict[str, Any]]) -> list[str]:
    """The Markdown table's columns: system, method, seed, status, the ``columns`` of each kind present (in the order
    the kinds first appear), then the wall time."""
    out = list(LEADING)
    for r in records:
        for c in KINDS[r["kind"]].columns if r.get("kind") in KINDS else ():
            if c not in out:
                out.append(c)
    return [*out, "wall_seconds"]


def _cell(value: Any, column: str = "") -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.2f}" if column.endswith("_seconds") else f"{value:.6g}"
    if isinstance(value, (list, dict)):
        return json.dumps(value, separators=(",", ":"))
    return str(value)


def _system(record: dict[str, Any]) -> str:
    """The system's own name (a spec loaded by path is named as in its file, not by the path); the name or path as
    given where the task failed before loading it."""
    return record.get("system_name") or record["system"]


def markdown(records: Sequence[dict[str, Any]]) -> str:
    """The Markdown table, then one line per task that is not ``ok`` with its message."""
    cols = columns(records)
    head = [c[:-len("_seconds")] + " s" if c.endswith("_seconds") else c for c in cols]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(cols)]
    for r in records:
        named = {**r, "system": _system(r)}
        cells = [_cell(named.get(c), c).replace("|", "\\|").replace("\n", " ") for c in cols]
        lines.append("| " + " | ".join(cells) + " |")
    bad = [r for r in records if r.get("status") != "ok"]
    if bad:
        lines.append("")
        lines += [f"- {_system(r)} / {r['method']} / seed {r['seed']}: {r['status']}: {r.get('message', '')}"
                  for r in bad]
    return "\n".join(lines) + "\n"


def csv_text(records: Sequence[dict[str, Any]]) -> str:
    """Every field of every record, one row each (fields a record lacks are empty)."""
    fields = list(LEADING)
    for r in records:
        fields += [k for k in r if k not in fields]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for r in records:
        writer.writerow({k: json.dumps(v, separators=(",", ":")) if isinstance(v, (list, dict)) else v
                         for k, v in r.items()})
    return buf.getvalue()


def json_text(records: Sequence[dict[str, Any]], config: dict[str, Any] | None = None) -> str:
    """The records (and the sweep's configuration record) as strict JSON (no NaN)."""
    doc = {"format": FORMAT, "version": VERSION, "config": config, "records": list(records)}
    return json.dumps(doc, indent=1, allow_nan=False) + "\n"


def write_tables(records: Sequence[dict[str, Any]], *, json_path: str | os.PathLike | None = None,
                 csv_path: str | os.PathLike | None = None, markdown_path: str | os.PathLike | None = None,
                 config: dict[str, Any] | None = None) -> list[Path]:
    """Write the tables asked for, each atomically; returns their paths."""
    out = []
    for path, text in ((json_path, lambda: json_text(records, config)), (csv_path, lambda: csv_text(records)),
                       (markdown_path, lambda: markdown(records))):
        if path is not None:
            out.append(atomic_write_text(path, text()))
    return out
