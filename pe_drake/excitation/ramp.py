"""Start and end at rest: the controller motion = ramp-in + N periods + ramp-out.

The optimized path q_F (Eq. 50) moves at full speed at t = 0. The motion sent to the controller
is a time scaling of that same path, q(t) = q_F(s(t)), v = q_F'(s)·ṡ, v̇ = q_F''(s)·ṡ² + q_F'(s)·s̈,
with ṡ rising from 0 to 1 over the ramp duration T_r by the smootherstep σ(x) = 6x⁵ − 15x⁴ + 10x³
(x = t/T_r): σ, σ', σ'' vanish at 0 and σ(1) = 1, σ'(1) = σ''(1) = 0, so the motion starts at
rest and q, v, v̇ and the jerk are continuous at the joins. ∫₀¹σ = 1/2: the ramp-in covers
s ∈ [−T_r/2, 0]; the ramp-out mirrors it.

Every posture of a ramp lies on the optimized path, so position limits, collision and the
quasi-static balance already hold there; what is new is the term q_F'·s̈ (|s̈| ≤ 1.875/T_r):
:func:`choose_ramp_duration` takes the shortest T_r of a short list for which every limit and
sampled constraint holds at 1 kHz over both ramps. Time axis (``RampedMotion.layout``):
[0, T_r] ramp-in, [T_r, T_r + N·P] the periods, then the ramp-out; at rest outside.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from pe_drake.exceptions import ConfigError, InfeasibleError, NotWithinLimitsError
from pe_drake.excitation.constraints.base import state_margins
from pe_drake.excitation.fourier import FourierTrajectory

#: Ramp durations tried in order by :func:`choose_ramp_duration` [s].
RAMP_DURATIONS = (1.0, 2.0, 3.0, 5.0, 8.0, 13.0)
#: Longest ramp read from a motion file [s] (optimize writes a few seconds).
MAX_RAMP_S = 600.0
#: Longest whole motion read from a motion file [s]: ramps and periods (identification runs
#: last minutes; each reader samples the whole motion at up to 1 kHz).
MAX_MOTION_S = 7200.0


def smootherstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(S, σ, σ', σ'') at x (clipped to [0, 1]): σ(x) = 6x⁵ − 15x⁴ + 10x³ and its integral
    S(x) = x⁶ − 3x⁵ + 5x⁴/2, each the shape of x."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    x2 = x * x
    S = x2 * x2 * (x2 - 3.0 * x + 2.5)
    sigma = x2 * x * (6.0 * x2 - 15.0 * x + 10.0)
    d_sigma = 30.0 * x2 * (1.0 - x) ** 2
    dd_sigma = 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x)
    return S, sigma, d_sigma, dd_sigma


def _check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{name} must be a finite number {bound}, got {value!r}")
    return value


def check_periods(periods) -> int:
    """Validates a number of periods (a positive integer, at most 1000) or raises ConfigError."""
    if isinstance(periods, bool) or not isinstance(periods, (int, np.integer)) or not 1 <= periods <= 1000:
        raise ConfigError(f"periods must be an integer from 1 to 1000, got {periods!r}")
    return int(periods)


@dataclasses.dataclass(frozen=True)
class PathTiming:
    """The time scaling s(t) at some times: s, ṡ, s̈ (each shape (T,))."""

    s: np.ndarray
    s_dot: np.ndarray
    s_ddot: np.ndarray


@dataclasses.dataclass(frozen=True)
class RampedMotion:
    """Ramp-in + ``periods`` periods of ``path`` (q_F) + ramp-out (module docstring).

    Attributes:
        ramp_duration: T_r [s]; 0: no ramps (N periods of the path, not starting at rest).
        phase: path time φ at which the periodic part starts [s], in [0, P): the periodic
            part is q_F(t − T_r + φ), and both joins sit at the path's phase φ.
    """

    path: FourierTrajectory
    periods: int = 1
    ramp_duration: float = 0.0
    phase: float = 0.0

    def __post_init__(self):
        check_periods(self.periods)
        _check_positive("ramp_duration", self.ramp_duration, allow_zero=True)
        _check_positive("omega", self.path.omega)
        if not 0.0 <= _check_positive("phase", self.phase, allow_zero=True) < self.path.period:
            raise ConfigError(f"phase must lie in [0, period = {self.path.period:.6g}) [s], got {self.phase!r}")

    @property
    def num_joints(self) -> int:
        return self.path.num_joints

    @property
    def period(self) -> float:
        """The whole motion's duration (so that code written for one period of a
        :class:`FourierTrajectory` replays the whole motion) [s]."""
        return self.duration

    @property
    def periodic_start(self) -> float:
        """Time at which the periodic part starts (= T_r) [s]."""
        return float(self.ramp_duration)

    @property
    def periodic_end(self) -> float:
        """Time at which the periodic part ends (= T_r + N·P) [s]."""
        return self.ramp_duration + self.periods * self.path.period

    @property
    def duration(self) -> float:
        """Whole motion, 2·T_r + N·P [s]."""
        return self.periodic_end + self.ramp_duration

    @property
    def layout(self) -> dict[str, list[float]]:
        """{part: [start, end]} [s]: ``ramp_in``, ``periodic``, ``ramp_out``."""
        start, end = self.periodic_start, self.periodic_end
        return {"ramp_in": [0.0, start], "periodic": [start, end], "ramp_out": [end, self.duration]}

    def timing(self, t: np.ndarray) -> PathTiming:
        """s(t), ṡ(t), s̈(t) of the time scaling (constant rest outside [0, duration])."""
        t = np.asarray(t, float).reshape(-1)
        Tr, t1, t2 = self.ramp_duration, self.periodic_start, self.periodic_end
        s = t - t1
        s_dot = np.ones_like(t)
        s_ddot = np.zeros_like(t)
        if Tr > 0:
            half = 0.5 * Tr
            into = t < t1
            S, sig, dsig, _ = smootherstep(t[into] / Tr)
            s[into] = -half + Tr * S
            s_dot[into] = sig
            s_ddot[into] = dsig / Tr
            out = t > t2
            y = (t[out] - t2) / Tr
            S1, sig1, dsig1, _ = smootherstep(1.0 - y)
            s[out] = (t2 - t1) + half - Tr * S1
            s_dot[out] = sig1
            s_ddot[out] = -dsig1 / Tr
        else:
            s = np.clip(s, 0.0, t2 - t1)
            outside = (t < t1) | (t > t2)
            s_dot[outside] = 0.0
        return PathTiming(s + self.phase, s_dot, s_ddot)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, v, v̇ at times t, each shape (T, n) [rad, rad/s, rad/s²]."""
        timing = self.timing(t)
        q, dq, ddq = self.path.evaluate(timing.s)  # path derivatives with respect to s
        sd, sdd = timing.s_dot[:, None], timing.s_ddot[:, None]
        return q, dq * sd, ddq * sd * sd + dq * sdd

    def sample_times(self, rate: float) -> np.ndarray:
        """Times 0, 1/rate, ... covering the whole motion; the last is at or just after the
        end (the motion rests there), so the grid stays uniform."""
        rate = _check_positive("sample rate", rate)
        count = int(math.ceil(self.duration * rate - 1e-6)) + 1
        return np.arange(count) / rate

    def to_dict(self) -> dict:
        """The keys trajectory.json records for the ramp (see :func:`ramped_motion_from_dict`)."""
        return {"periods": self.periods, "ramp_duration": self.ramp_duration, "phase": self.phase,
                "motion_duration": self.duration, "layout": self.layout}


def ramped_motion_from_dict(path: FourierTrajectory, data: dict, *, source: str = "trajectory.json") -> RampedMotion:
    """The motion a trajectory.json describes (one period without ramps if it gives none);
    ConfigError naming the file for a bad ``periods``, ``ramp_duration`` or ``phase``."""
    try:
        motion = RampedMotion(
            path, check_periods(data.get("periods", 1)),
            _check_positive("ramp_duration", data.get("ramp_duration", 0.0), allow_zero=True),
            _check_positive("phase", data.get("phase", 0.0), allow_zero=True))
        # Every reader samples the whole motion: 'ramp_duration: 1e9' asked for 447 GiB.
        for name, value, most in (("ramp_duration", motion.ramp_duration, MAX_RAMP_S),
                                  ("the whole motion (ramps and periods)", motion.duration, MAX_MOTION_S)):
            if value > most:
                raise ConfigError(f"{name} is {value:.6g} s, over the {most:g} s pe_drake reads from a motion file")
        return motion
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from err


@dataclasses.dataclass(frozen=True)
class RampCheck:
    """Outcome of checking one ramp duration T_r [s] at join phase φ [s]: the minimum margin of
    each limit and constraint over both ramps, and the ``worst`` (most violated) entry."""

    ramp_duration: float
    phase: float
    margins: dict[str, float]
    worst: str

    @property
    def ok(self) -> bool:
        return self.margins[self.worst] >= 0.0


def check_within_limits(
    motion: RampedMotion, limits, joint_names: Sequence[str], *, source: str = "", rate: float = 200.0, slack: float = 1e-3
) -> None:
    """Refuses (NotWithinLimitsError) a motion, e.g. from a hand-edited trajectory.json, that
    leaves the robot's position or velocity limits, before any work is done with it."""
    t = motion.sample_times(min(rate, 1e5 / max(motion.duration, 1e-9)))
    q, v, _ = motion.evaluate(t)
    for what, x, lo, hi in (
        ("position", q, limits.q_lower - slack, limits.q_upper + slack),
        ("velocity", v, -limits.v_max - slack, limits.v_max + slack),
    ):
        over = np.maximum(lo - x, x - hi)
        if np.any(over > 0):
            k, j = np.unravel_index(int(np.argmax(over)), over.shape)
            where = f"{source}, " if source else ""
            raise NotWithinLimitsError(
                joint_names[j], float(x[k, j]), float(lo[j] + slack), float(hi[j] - slack),
                f"{what} ({where}t = {t[k]:.3f} s of the motion)",
            )


#: Significant digits of the numbers in trajectory.csv (trajectory_file.write_motion_csv).
CSV_DIGITS = 9
#: Samples evaluated at a time by :func:`check_written_motion`.
WRITTEN_CHUNK = 100_000
#: Allowance of :func:`limit_excess`: the float rounding of a limit itself, relative to it.
LIMIT_ROUNDING = 1e-12


class LimitExcess(NamedTuple):
    """The worst excess of a joint limit by written values (:func:`limit_excess`)."""

    quantity: str  # "position", "velocity" or "acceleration"
    joint: int
    sample: int
    value: float  # as written [rad or m, /s, /s²]
    excess: float  # beyond the limit, > 0 [same unit]


def limit_excess(q: np.ndarray, v: np.ndarray, vd: np.ndarray, limits, digits: int = CSV_DIGITS) -> LimitExcess | None:
    """The worst value beyond a joint limit once written with ``digits`` significant digits,
    or None: no excess beyond :data:`LIMIT_ROUNDING` of the limit. ``q, v, vd``: shape (T, n).

    Rounding is monotone, so only each column's extremes are rounded.
    """
    worst = None
    for name, x, lo, hi in (
        ("position", q, limits.q_lower, limits.q_upper),
        ("velocity", v, -limits.v_max, limits.v_max),
        ("acceleration", vd, -limits.vd_max, limits.vd_max),
    ):
        x = np.asarray(x, float)
        if x.size == 0:
            continue
        for which, bound, sign in ((np.argmax, hi, 1.0), (np.argmin, lo, -1.0)):
            k = which(x, axis=0)
            written = np.array([float(f"{x[k[j], j]:.{digits}g}") for j in range(x.shape[1])])
            excess = sign * (written - bound) - LIMIT_ROUNDING * np.abs(bound)
            j = int(np.argmax(excess))
            if excess[j] > 0 and (worst is None or excess[j] > worst.excess):
                worst = LimitExcess(name, j, int(k[j]), float(written[j]), float(sign * (written[j] - bound[j])))
    return worst


def check_written_motion(motion: RampedMotion, limits, joint_names: Sequence[str], rate: float) -> None:
    """Refuses (NotWithinLimitsError) a motion whose trajectory.csv at ``rate`` [Hz] would hold a
    value outside a joint limit beyond the limit's float rounding (:func:`limit_excess`)."""
    t = motion.sample_times(rate)
    worst = None
    for start in range(0, len(t), WRITTEN_CHUNK):  # in chunks: a 1000-period motion has 10⁷ rows
        found = limit_excess(*motion.evaluate(t[start:start + WRITTEN_CHUNK]), limits)
        if found is not None and (worst is None or found.excess > worst.excess):
            worst = found._replace(sample=found.sample + start)
    if worst is not None:
        j = worst.joint
        lo, hi = {"position": (limits.q_lower, limits.q_upper), "velocity": (-limits.v_max, limits.v_max),
                  "acceleration": (-limits.vd_max, limits.vd_max)}[worst.quantity]
        raise NotWithinLimitsError(
            joint_names[j], worst.value, float(lo[j]), float(hi[j]),
            f"{worst.quantity} (by {worst.excess:.3g} at t = {t[worst.sample]:.3f} s of the written motion at "
            f"{rate:g} Hz)",
        )


def ramp_margins(motion: RampedMotion, limits, constraints: Sequence = (), rate: float = 1000.0) -> dict[str, float]:
    """Minimum margin of the joint limits and each sampled constraint over the two ramps
    checked at ``rate`` [Hz] (:func:`~pe_drake.excitation.constraints.base.state_margins`)."""
    t = motion.sample_times(rate)
    in_ramp = (t <= motion.periodic_start) | (t >= motion.periodic_end)
    return state_margins(limits, constraints, *motion.evaluate(t[in_ramp]))


def _ramp_within_limits(motion: RampedMotion, limits, rate: float) -> bool:
    t = motion.sample_times(rate)
    in_ramp = (t <= motion.periodic_start) | (t >= motion.periodic_end)
    return limit_excess(*motion.evaluate(t[in_ramp]), limits) is None


def phase_candidates(path: FourierTrajectory, limits, count: int = 3, window: float = 0.25, rate: float = 1000.0) -> list[float]:
    """Path phases where a ramp may join best: 0 first, then the ``count`` phases (of 16 evenly
    spread) with the most acceleration headroom within ±``window`` [s].

    Near a join ṡ → 1 while s̈ → 0 more slowly than 1 − ṡ, so v̇ = q_F''ṡ² + q_F's̈ exceeds
    |q_F''| slightly whenever both have the same sign: a path whose acceleration limit is
    active at the join cannot be ramped at any T_r (the excess falls like T_r⁻³). Joining
    at a phase where the path has headroom avoids that.
    """
    P = path.period
    t = np.arange(0.0, P, 1.0 / rate)
    _, _, vd = path.evaluate(t)
    headroom = np.min(1.0 - np.abs(vd) / limits.vd_max, axis=1)  # (T,), fraction of the limit
    phases = np.arange(16) * (P / 16)
    scores = []
    for phi in phases:
        gap = np.abs((t - phi + 0.5 * P) % P - 0.5 * P)  # circular distance to phi
        scores.append(float(np.min(headroom[gap <= window])))
    order = [float(phases[k]) for k in np.argsort(scores)[::-1] if phases[k] > 0]
    return [0.0] + order[:count]


def choose_ramp_duration(
    path: FourierTrajectory, limits, constraints: Sequence = (), *, periods: int = 1,
    durations: Sequence[float] = RAMP_DURATIONS, rate: float = 1000.0, tolerance: float = 1e-6,
) -> tuple[RampedMotion, list[RampCheck]]:
    """The shortest ramp duration of ``durations`` for which every limit and constraint holds
    on both ramps at ``rate``, trying the phases of :func:`phase_candidates` at each.

    Returns the :class:`RampedMotion` and the checks made; raises InfeasibleError when no
    duration works.
    """
    checks = []
    phases = phase_candidates(path, limits, rate=rate)
    for Tr in durations:
        for phase in phases:
            motion = RampedMotion(path, periods, float(Tr), phase)
            margins = ramp_margins(motion, limits, constraints, rate)
            worst = min(margins, key=margins.get)
            checks.append(RampCheck(float(Tr), phase, margins, worst))
            # The sampled constraints (collision, balance, torque) within the solver's
            # tolerance; the joint limits strictly, as written (nothing outside is valid).
            if margins[worst] >= -tolerance and _ramp_within_limits(motion, limits, rate):
                return motion, checks
    last = max(checks[-len(phases):], key=lambda c: c.margins[c.worst])
    raise InfeasibleError(
        f"no ramp from rest within the limits: with the longest ramp tried ({last.ramp_duration:g} s) "
        f"the {last.worst} margin is {last.margins[last.worst]:.4g} on the ramps (negative: violated); "
        "lower robot.acceleration_scale or robot.velocity_scale for more headroom, allow longer "
        "ramps, or set excitation.ramp: false (the motion then does not start at rest)"
    )
