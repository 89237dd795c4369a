"""A part of a run, by time, taken after the whole run is filtered (``--window START,END``).

Cutting the file first would give the filter two new ends, each with its edge transient;
filtering the whole run and keeping the window's samples leaves no edge at the cut, so
``identify --window`` and ``validate --window`` reproduce the training and held-out parts that
``diagnose`` prints.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pe_drake.exceptions import ConfigError, DataError
from pe_drake.identification.measurements import Measurement


@dataclasses.dataclass(frozen=True)
class TimeWindow:
    """Samples with ``start`` ≤ t ≤ ``end``, in the file's own time [s]; None: that end of the run.

    Raises:
        ConfigError: a non-finite bound, or start ≥ end.
    """

    start: float | None = None
    end: float | None = None

    def __post_init__(self) -> None:
        for name in ("start", "end"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise ConfigError(f"--window {name} must be a finite time [s], got {value}")
        if self.start is not None and self.end is not None and self.start >= self.end:
            raise ConfigError(f"--window start {self.start:g} s must come before its end {self.end:g} s")

    @classmethod
    def parse(cls, text: str) -> TimeWindow:
        """``"START,END"``, ``",END"`` or ``"START,"`` [s]."""
        parts = str(text).split(",")
        if len(parts) != 2:
            raise ConfigError(f"--window takes START,END in seconds (either may be empty, e.g. ',14.7'), got '{text}'")
        try:
            start, end = (float(p) if p.strip() else None for p in parts)
        except ValueError:
            raise ConfigError(f"--window takes START,END in seconds (numbers), got '{text}'") from None
        return cls(start, end)

    def __str__(self) -> str:
        start = "the start" if self.start is None else f"{self.start:g} s"
        end = "the end" if self.end is None else f"{self.end:g} s"
        return f"{start} to {end}"

    def apply(self, data: Measurement) -> Measurement:
        """The samples of ``data`` (preprocessed or not) inside the window; DataError below 2."""
        t = data.t
        keep = np.ones(t.shape, bool)
        if self.start is not None:
            keep &= t >= self.start
        if self.end is not None:
            keep &= t <= self.end
        kept = int(keep.sum())
        if kept < 2:
            raise DataError(f"--window {self} keeps {kept} sample(s) of a run that spans "
                            f"{t[0]:.4g}-{t[-1]:.4g} s (after filtering and trimming)", file=data.source)

        info = data.preprocessing
        if info is not None:
            span = float(t[keep][-1] - t[keep][0])
            info = dataclasses.replace(info, samples_out=kept, duration_out_s=span)
        note = (f"--window: {kept} of {t.size} samples kept, {t[keep][0]:.4g}-{t[keep][-1]:.4g} s "
                "(the whole run was filtered first: no filter edge at the cut)")
        return data.take(keep).replace(preprocessing=info, notes=data.notes + (note,))
