"""Registries that drive the parametrised tests (a meta-test checks they are complete)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SPECS_DIR = ROOT / "specs"
ALL_SPECS = sorted(SPECS_DIR.glob("*.yaml"))
ALL_SPEC_NAMES = [p.stem for p in ALL_SPECS]
