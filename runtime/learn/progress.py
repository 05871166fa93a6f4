"""Progress meters for the learners' loops and the sweep (Diffrax's ``TqdmProgressMeter`` / ``NoProgressMeter`` idea)
behind one interface, so a loop never asks which: a bar on a terminal, a plain line every few seconds in a log file
or a pipe (where a bar redrawn in place shows as nothing, or as garbage).

    with progress_meter(None, total=600, initial=0, desc="fit van_der_pol", unit="epoch") as meter:
        meter.update("train 1.2e-03")   # one step done, and what to show beside the bar (None: keep the last)
"""

from __future__ import annotations

import os
import sys
import time
from typing import Callable

__all__ = ["LineProgressMeter", "NoProgressMeter", "TqdmProgressMeter", "progress_meter"]

# Seconds between two progress lines when stderr is not a terminal; $MYRIAD_PROGRESS_SECONDS overrides it.
LINE_SECONDS = 10.0


class NoProgressMeter:
    """Shows nothing (a test, a sweep's worker, ``progress=False``)."""

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


class LineProgressMeter(NoProgressMeter):
    """A line on stderr at the first step ``seconds`` or more after the last line (or the start), e.g.
    ``fit van_der_pol: epoch 120/600, train 3.2e-04, 12.3 s``, and one at the end of a run that printed any."""

    def __init__(self, total: int, initial: int, desc: str, unit: str, seconds: float = LINE_SECONDS,
                 clock: Callable[[], float] = time.monotonic):
        self._total, self._done, self._desc, self._unit = total, initial, desc, unit
        self._seconds, self._clock = seconds, clock
        self._start = self._last = clock()
        self._postfix, self._shown = None, None  # the last postfix; the count at the last line (None: no line yet)

    def update(self, postfix: str | None = None) -> None:
        self._done += 1
        self._postfix = self._postfix if postfix is None else postfix
        if self._clock() - self._last >= self._seconds:
            self._line()

    def _line(self) -> None:
        self._last, self._shown = self._clock(), self._done
        postfix = "" if self._postfix is None else f", {self._postfix}"
        print(f"{self._desc}: {self._unit} {self._done}/{self._total}{postfix}, {self._last - self._start:.1f} s",
              file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._shown is not None and self._shown != self._done:
            self._line()


def progress_meter(progress: bool | None, total: int, *, initial: int = 0, desc: str = "",
                   unit: str = "it") -> NoProgressMeter:
    """``progress`` True: a :class:`TqdmProgressMeter`; False: a :class:`NoProgressMeter`; None: a bar when stderr
    is a terminal, else a :class:`LineProgressMeter` (every ``$MYRIAD_PROGRESS_SECONDS``, default 10 s)."""
    if progress is False:
        return NoProgressMeter()
    if progress or sys.stderr.isatty():
        return TqdmProgressMeter(total, initial, desc, unit)
    text, seconds = os.environ.get("MYRIAD_PROGRESS_SECONDS", ""), LINE_SECONDS
    try:
        seconds = float(text) if text else seconds
    except ValueError:  # a progress setting is not worth stopping a run for
        print(f"myriad: warning: MYRIAD_PROGRESS_SECONDS={text!r} is not a number of seconds; using {seconds:g}",
              file=sys.stderr)
    return LineProgressMeter(total, initial, desc, unit, seconds)
