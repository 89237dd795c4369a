"""Holes in a recording's time column: dropped packets are interpolated, pauses split the run.

A *hole* is a time step longer than :data:`HOLE_STEPS` median steps. One of at most
``max_gap_s`` (:data:`MAX_GAP_S`, config ``data.max_gap_s``) is interpolated linearly by the
uniform grid, with a note: at a cut-off of a few Hz, 20 ms of straight line is far below the
filter's own smoothing. A longer one is a pause: the run is split there into segments, each
filtered, differentiated and trimmed on its own (:func:`preprocess_segments`), and their samples
are stacked (the rows of Eq. 4 need not be contiguous in time). The diagnosis assumes one
contiguous record: :func:`longest_segment` gives it the longest one.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.identification.csv_checks import check_time_order
from pe_drake.identification.measurements import SAMPLE_FIELDS, Measurement
from pe_drake.identification.preprocessing import (PreprocessOptions, choose_cutoff, preprocess,
                                                   resample_uniform)

#: Longest hole interpolated [s]; longer ones split the run (config ``data.max_gap_s``).
MAX_GAP_S = 0.02
#: A time step longer than this many median steps is a hole.
HOLE_STEPS = 5.0


class Gaps(NamedTuple):
    """The median time step [s] and the indices k of the holes t[k] → t[k+1]: those short
    enough to interpolate and the pauses where the run is split (:func:`find_gaps`)."""

    step: float
    interpolated: np.ndarray
    splits: np.ndarray


def find_gaps(t: np.ndarray, max_gap_s: float = MAX_GAP_S) -> Gaps:
    """The holes of strictly increasing ``t`` (T,) [s]: interpolated ones and pauses (longer
    than ``max_gap_s`` [s] and than ``HOLE_STEPS`` median steps)."""
    t = np.asarray(t, float)
    if len(t) < 3:
        return Gaps(0.0, np.empty(0, int), np.empty(0, int))
    dt = np.diff(t)
    step = float(np.median(dt))
    holes = np.flatnonzero(dt > HOLE_STEPS * step)
    limit = max(float(max_gap_s), HOLE_STEPS * step)
    long = dt[holes] > limit + 1e-12
    return Gaps(step, holes[~long], holes[long])


def _gap_notes(t: np.ndarray, gaps: Gaps, max_gap_s: float) -> list[str]:
    notes = []
    dt = np.diff(t)
    if gaps.interpolated.size:
        longest = float(dt[gaps.interpolated].max())
        notes.append(f"{gaps.interpolated.size} hole(s) in the time column of up to "
                     f"{longest * 1e3:.3g} ms (≤ data.max_gap_s = {max_gap_s * 1e3:.3g} ms) "
                     "interpolated linearly")
    if gaps.splits.size:
        where = ", ".join(f"{dt[k]:.4g} s at t = {t[k]:.6g} s" for k in gaps.splits[:5])
        more = f" and {gaps.splits.size - 5} more" if gaps.splits.size > 5 else ""
        notes.append(f"{gaps.splits.size} pause(s) longer than data.max_gap_s = "
                     f"{max_gap_s * 1e3:.3g} ms ({where}{more}): the run is split into "
                     f"{gaps.splits.size + 1} segments, each filtered on its own")
    return notes


def split_at_pauses(measurement: Measurement, max_gap_s: float = MAX_GAP_S) -> tuple[list[Measurement], list[str]]:
    """(segments between the pauses of a raw measurement in time order, notes on the holes);
    one segment (the measurement itself) without pauses.

    Raises:
        DataError: repeated or decreasing time stamps (counted, not thousands of "holes").
    """
    check_time_order(measurement.t, measurement.source)
    gaps = find_gaps(measurement.t, max_gap_s)
    notes = _gap_notes(measurement.t, gaps, max_gap_s)
    bounds = [0, *(int(k) + 1 for k in gaps.splits), measurement.num_samples]
    if len(bounds) == 2:
        return [measurement], notes
    return [measurement.take(slice(a, b)) for a, b in zip(bounds[:-1], bounds[1:])], notes


def _common_options(segments: list[Measurement], options: PreprocessOptions) -> tuple[PreprocessOptions, str | None]:
    """Options with one cut-off for every segment (chosen on the longest one when automatic)."""
    if options.cutoff_hz is not None:
        return options, None
    longest = max(segments, key=lambda s: s.num_samples)
    grid = resample_uniform(longest.t, {"q": longest.q})
    cutoff = choose_cutoff(grid.t, grid.signals["q"], grid.rate_hz, fundamental_hz=options.fundamental_hz,
                           harmonics=options.harmonics, file=longest.source)
    return dataclasses.replace(options, cutoff_hz=cutoff.hz, fundamental_hz=None, harmonics=None), cutoff.source


def preprocess_segments(measurement: Measurement, options: PreprocessOptions | None = None,
                        max_gap_s: float = MAX_GAP_S) -> Measurement:
    """:func:`~pe_drake.identification.preprocessing.preprocess` of each segment, stacked.

    Every segment gets the same cut-off (the automatic one is chosen on the longest segment)
    and its own filter, derivatives and trimmed ends; one too short for the filter is left out
    with a note. Sample counts and durations of ``preprocessing`` are summed over segments.

    Raises:
        DataError: no segment is long enough; as ``preprocess``.
    """
    options = options or PreprocessOptions()
    segments, notes = split_at_pauses(measurement, max_gap_s)
    notes = list(measurement.notes) + notes
    if len(segments) == 1:
        return preprocess(measurement, options).replace(notes=tuple(notes))
    common, source = _common_options(segments, options)
    done, dropped = [], []
    for k, seg in enumerate(segments):
        try:
            done.append(preprocess(seg, common))
        except DataError:
            dropped.append(f"{k + 1} ({seg.duration:.3g} s from t = {seg.t[0]:.6g} s)")
    if not done:
        raise DataError(f"none of the {len(segments)} segments between the pauses is long enough to filter; "
                        "record longer stretches or raise data.max_gap_s", file=measurement.source)
    if dropped:
        notes.append(f"segment(s) {', '.join(dropped)} too short for the filter: left out")
    info = done[0].preprocessing
    info = dataclasses.replace(
        info, cutoff_source=source or info.cutoff_source, segments=len(done),
        samples_in=measurement.num_samples, samples_out=sum(d.num_samples for d in done),
        duration_in_s=sum(s.duration for s in segments),
        duration_out_s=sum(d.preprocessing.duration_out_s for d in done),
        resampled=any(d.preprocessing.resampled for d in done),
    )
    stacked = {f: None if getattr(done[0], f) is None else np.concatenate([getattr(d, f) for d in done])
               for f in SAMPLE_FIELDS}
    return measurement.replace(**stacked, preprocessing=info, notes=tuple(notes))


def longest_segment(measurement: Measurement, max_gap_s: float = MAX_GAP_S) -> Measurement:
    """The longest segment between pauses (for the diagnosis), with notes on what was left out."""
    segments, notes = split_at_pauses(measurement, max_gap_s)
    notes = list(measurement.notes) + notes
    best = max(segments, key=lambda s: s.duration)
    if len(segments) > 1:
        notes.append(f"the diagnosis uses one contiguous record: the longest segment, "
                     f"{best.duration:.4g} s from t = {best.t[0]:.6g} s, of {len(segments)} (its "
                     "held-out split, delay and pre-sliding terms follow time)")
    return best.replace(notes=tuple(notes))
