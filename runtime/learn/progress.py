"""Progress meters for the learners' loops (Diffrax's ``TqdmProgressMeter`` / ``NoProgressMeter`` idea): a tqdm bar
on stderr when a person is watching, nothing otherwise, behind one interface so a loop never asks which.

    with progress_meter(None, total=600, initial=0, desc="fit van_der_pol", unit="epoch") as meter:
        meter.update("train 1.2e-03")   # one step done, and what to show beside the bar (None: keep the last)
"""

from __future__ import annotations

import sys

__all__ = ["NoProgressMeter", "TqdmProgressMeter", "progress_meter"]


class NoProgressMeter:
    """Shows nothing (a log file, a test, a sweep's worker)."""

    def update(self, postfix: str | None = None) -> None:
        """One step done; ``postfix`` is what to show beside the bar."""

    def close(self) -> None:
        pass

    def __enter__(self) -> NoProgressMeter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class TqdmProgressMeter(NoProgressMeter):
    """A tqdm bar on stderr, counting ``unit`` from ``initial`` (a resumed run) to ``total``."""

    def __init__(self, total: int, initial: int, desc: str, unit: str):
        from tqdm import tqdm  # lazily: only a bar needs it

        self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True)

    def update(self, postfix: str | None = None) -> None:
        self._bar.update(1)
        if postfix is not None:
            self._bar.set_postfix_str(postfix)

    def close(self) -> None:
        self._bar.close()


def progress_meter(progress: bool | None, total: int, *, initial: int = 0, desc: str = "",
                   unit: str = "it") -> NoProgressMeter:
    """A :class:`TqdmProgressMeter` when ``progress`` is True, or None and stderr is a terminal; else a
    :class:`NoProgressMeter`."""
    if not (sys.stderr.isatty() if progress is None else progress):
        return NoProgressMeter()
    return TqdmProgressMeter(total, initial, desc, unit)

