"""A joint's limits from the model file and the config: placeholders replaced, real limits only
tightened."""

from __future__ import annotations

import numpy as np

from pe_drake.exceptions import ConfigError

#: A model file's velocity limit above this is taken for a placeholder and named (rad/s on a
#: revolute joint, m/s on a prismatic one): the fastest arm and humanoid joints turn at 3-30 rad/s.
PLAUSIBLE_VELOCITY = {"revolute": 50.0, "prismatic": 10.0}

#: Units of a joint's position and its first three time derivatives, by joint kind.
JOINT_UNITS = {"revolute": ("rad", "rad/s", "rad/s²", "rad/s³"), "prismatic": ("m", "m/s", "m/s²", "m/s³")}


def joint_unit(kind: str, derivative: int = 0) -> str:
    """The unit of a joint's position (``derivative`` 0), velocity (1), acceleration (2) or jerk."""
    return JOINT_UNITS.get(kind, JOINT_UNITS["revolute"])[derivative]


#: Units of a joint's effort (torque or force), by joint kind.
EFFORT_UNITS = {"revolute": "N·m", "prismatic": "N"}


def effort_label(kinds) -> str:
    """The unit of the efforts of joints of ``kinds``: N·m, N, or both when a robot has both."""
    units = sorted({EFFORT_UNITS.get(k, "N·m") for k in kinds}, reverse=True)
    return units[0] if len(units) == 1 else "N·m; N for prismatic joints"


def merge_limits(name: str, model_range, model_velocity: float, cfg, model_file: str = "the model"):
    """A joint's position range and velocity limit (lower, upper, velocity) from model and config.

    A zero-width model range or a zero velocity limit (placeholders) is replaced by the config's
    value; a real model limit can only be tightened, and a wider config value is refused with a
    ConfigError naming both values.
    """
    lo, hi = float(model_range[0]), float(model_range[1])
    v = float(model_velocity)
    if name in cfg.position_limits:
        c_lo, c_hi = (float(x) for x in cfg.position_limits[name])
        if hi - lo > 0 and (c_lo < lo - 1e-12 or c_hi > hi + 1e-12):
            raise ConfigError(
                f"robot.position_limits['{name}'] = [{c_lo:g}, {c_hi:g}] is wider than the limits "
                f"[{lo:g}, {hi:g}] in {model_file}; a config can only tighten a real model limit "
                "(it replaces zero-width placeholders)")
        lo, hi = c_lo, c_hi
    if name in cfg.velocity_limits:
        c_v = float(cfg.velocity_limits[name])
        if v > 0 and c_v > v + 1e-12:
            raise ConfigError(
                f"robot.velocity_limits['{name}'] = {c_v:g} is above the limit {v:g} in {model_file}; "
                "a config can only tighten a real model limit (it replaces zero placeholders)")
        v = c_v
    elif v == 0:
        v = np.inf  # a placeholder: refused below as "no velocity limit" unless the config gives one
    return lo, hi, v


def position_margins(cfg, joint_names, kinds, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The margin kept from each joint's position limits (n,) [rad or m], and the note on defaults.

    When pe_drake assumed ``robot.position_margin`` (a model without a config), a joint whose
    range is narrower than four margins keeps a quarter of its range instead, so that the default
    never empties a range the user did not ask to shrink.
    """
    margin = np.full(len(lower), float(cfg.position_margin))
    width = np.asarray(upper, float) - np.asarray(lower, float)
    assumed = set(cfg.assumed)
    narrow = []
    if "position_margin" in assumed:
        cut = np.isfinite(width) & (width < 4 * margin)
        margin[cut] = 0.25 * np.maximum(width[cut], 0.0)
        narrow = [name for name, c in zip(joint_names, cut) if c]
    parts = []
    if "position_margin" in assumed:
        unit = "rad (m on prismatic joints)" if "prismatic" in kinds else "rad"
        text = f"position margin {cfg.position_margin:g} {unit} from each limit"
        if narrow:
            text += f" (a quarter of the range on {', '.join(narrow)}: narrower than 4 margins)"
        parts.append(text)
    if "velocity_scale" in assumed:
        parts.append(f"{cfg.velocity_scale:.0%} of the velocity limits".replace("%", " %"))
    if not parts:
        return margin, []
    names = " and ".join(f"robot.{k}" for k in cfg.assumed)
    return margin, [f"defaults for a robot without a config: {', '.join(parts)} (set {names} in a config to change them)"]


def placeholder_velocity_notes(cfg, joint_names, kinds, velocity: np.ndarray) -> list[str]:
    """A note naming the joints whose model velocity limit looks like a placeholder (above
    :data:`PLAUSIBLE_VELOCITY`, not set in the config): only acceleration and range bound them."""
    high = [(name, v, kind) for name, v, kind in zip(joint_names, velocity, kinds)
            if name not in cfg.velocity_limits and np.isfinite(v) and v > PLAUSIBLE_VELOCITY.get(kind, 50.0)]
    if not high:
        return []
    listed = ", ".join(f"{name} {v:g} {joint_unit(kind, 1)}" for name, v, kind in high[:4])
    more = f" and {len(high) - 4} more" if len(high) > 4 else ""
    return [f"the model's velocity limits look like placeholders ({listed}{more}); the motion is bounded by "
            "the acceleration limits and the ranges: set robot.velocity_limits from the robot's datasheet"]
