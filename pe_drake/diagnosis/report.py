"""The diagnosis report: report.md and its figures (matplotlib, Agg backend, imported lazily),
and the one-line summary of the candidates' decisions (:mod:`pe_drake.diagnosis.decisions`).

Figures:

- ``torque_heldout.png``: measured torque on the held-out data against the a-priori model,
  the re-identified rigid-body model and the augmented model, per joint;
- ``residual_effects.png``: for each named effect, the held-out residual of its joint
  against the regime that exposes it (v for friction, v̇ for armature, time for an offset,
  time for a payload) before the effect was added and after; with no effect named, the
  rigid-body residual against v for every joint;
- ``regimes.png``: mean nominal residual per joint and regime (step 1);
- ``gap.png``: held-out RMS per joint, nominal → rigid → augmented;
- ``unexplained.png`` (when a joint is unexplained): its residual against time and dτ/dt.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pe_drake.diagnosis.options import KEPT
from pe_drake.io_utils import atomic_write_text
from pe_drake.plots import save_figure


def _plt():
    # matplotlib imported here: keeps `import pe_drake` light and headless.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_report(folder: str | Path, result, model_files: list[Path]) -> list[Path]:
    """Writes report.md and the figures into ``folder``; returns the figure paths."""
    folder = Path(folder)
    figures = [
        plot_torques(folder / "torque_heldout.png", result),
        plot_effect_residuals(folder / "residual_effects.png", result),
        plot_regimes(folder / "regimes.png", result),
        plot_gap(folder / "gap.png", result),
    ]
    if result.unexplained:
        figures.append(plot_unexplained(folder / "unexplained.png", result))
    atomic_write_text(folder / "report.md", report_markdown(result, [p.name for p in figures],
                                                            [Path(p).name for p in model_files]))
    return figures


def plot_torques(path: Path, result) -> Path:
    """torque_heldout.png: measured and model torques on the held-out data, per joint."""
    plt = _plt()
    p = result.predictions
    n = len(result.joints)
    fig, axes = plt.subplots(n, 1, figsize=(11, 1.7 * n + 0.8), sharex=True, constrained_layout=True)
    axes = np.atleast_1d(axes)
    for j, ax in enumerate(axes):
        ax.plot(p["t"], p["measured"][:, j], "k", lw=1.6, label="measured")
        ax.plot(p["t"], p["nominal"][:, j], "r--", lw=1, label="a-priori model")
        ax.plot(p["t"], p["rigid"][:, j], color="orange", lw=1, label="rigid re-identified")
        ax.plot(p["t"], p["after"][:, j], "b", lw=1, label="augmented (Drake)")
        ax.set_ylabel(f"{result.joints[j]}\n[N·m]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1].set_xlabel("t [s] (held-out data)")
    fig.suptitle("Measured vs model torque on the held-out data")
    return save_figure(fig, path)


_REGIME_LABELS = {"v": "v [rad/s]", "vd": "v̇ [rad/s²]", "q": "q [rad]", "dtau": "dτ/dt [N·m/s]"}


def _regime_signal(result, regime: str, joint: int) -> tuple[np.ndarray, str]:
    seg = result.held_out
    if regime in _REGIME_LABELS:
        return getattr(seg, regime)[:, joint], _REGIME_LABELS[regime]
    return seg.t, "t [s]"


def plot_effect_residuals(path: Path, result) -> Path:
    """residual_effects.png: each named effect's residual against its exposing regime."""
    plt = _plt()
    rs = result.residual_series
    panels: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, str, str, str]] = []
    for e in rs["effects"]:
        x, xl = _regime_signal(result, e["regime"], e["joint"])
        panels.append((e["label"], x, e["before"], e["after"], xl, "without this effect", "with all named"))
    payload = [e for e in result.effects if e.effect == "payload"]
    if payload:
        j = int(np.argmax(result.rms_nominal - result.rms_rigid))
        panels.append((f"payload on {payload[0].link} ({result.joints[j]})", result.held_out.t,
                       rs["nominal"][:, j], rs["rigid"][:, j], "t [s]", "a-priori model", "re-identified"))
    if not panels:
        for j, name in enumerate(result.joints):
            panels.append((f"{name}: no effect named", result.held_out.v[:, j], rs["rigid"][:, j],
                           rs["after"][:, j], "v [rad/s]", "rigid re-identified", "augmented"))
    cols = min(3, len(panels))
    rows = int(np.ceil(len(panels) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), constrained_layout=True, squeeze=False)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    for ax, (title, x, before, after, xl, lb, la) in zip(axes.ravel(), panels):
        ax.plot(x, before, ".", ms=1.5, color="0.6", label=lb)
        ax.plot(x, after, ".", ms=1.5, color="b", label=la)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(title, fontsize=8)
        ax.set_xlabel(xl, fontsize=8)
        ax.set_ylabel("held-out residual [N·m]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6, markerscale=5)
    fig.suptitle("Residual against the regime that exposes each effect: before and after")
    return save_figure(fig, path)


def plot_regimes(path: Path, result) -> Path:
    """regimes.png: mean nominal residual per joint and regime."""
    plt = _plt()
    joints = result.joints
    labels = [f"{b['regime']}: {b['bin']}" for b in result.regimes[joints[0]]["regimes"]]
    M = np.array([[b["mean"] for b in result.regimes[j]["regimes"]] for j in joints])
    scale = np.maximum(np.array([result.regimes[j]["overall"]["rms"] for j in joints]), 1e-12)
    fig, ax = plt.subplots(figsize=(11, 0.45 * len(joints) + 2.6), constrained_layout=True)
    im = ax.imshow(M / scale[:, None], cmap="coolwarm", vmin=-1.5, vmax=1.5, aspect="auto")
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(joints)))
    ax.set_yticklabels(list(joints), fontsize=8)
    for j in range(len(joints)):
        for k in range(len(labels)):
            ax.text(k, j, f"{M[j, k]:.2g}", ha="center", va="center", fontsize=5)
    fig.colorbar(im, ax=ax, label="mean residual / RMS residual of the joint")
    ax.set_title("Step 1: a-priori model residual (measured - model) per regime, mean [N·m]")
    return save_figure(fig, path)


def plot_gap(path: Path, result) -> Path:
    """gap.png: held-out RMS per joint, nominal → rigid → augmented, and the noise floor."""
    plt = _plt()
    n = len(result.joints)
    x = np.arange(n)
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * n + 2), 3.6), constrained_layout=True)
    for k, (label, values, color) in enumerate((("a-priori", result.rms_nominal, "r"),
                                                ("rigid re-identified", result.rms_rigid, "orange"),
                                                ("augmented", result.rms_after, "b"))):
        ax.bar(x + (k - 1) * 0.27, values, 0.27, label=label, color=color)
    ax.plot(x, result.noise_floor, "k_", ms=18, label="noise floor")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels(list(result.joints), fontsize=8)
    ax.set_ylabel("held-out RMS [N·m]")
    ax.legend(fontsize=7)
    ax.set_title("Held-out gap per joint")
    return save_figure(fig, path)


def plot_unexplained(path: Path, result) -> Path:
    """unexplained.png: each unexplained joint's residual against time and dτ/dt."""
    plt = _plt()
    names = list(result.unexplained)
    fig, axes = plt.subplots(len(names), 2, figsize=(10, 2.4 * len(names) + 0.6), constrained_layout=True,
                             squeeze=False)
    seg = result.held_out
    for row, name in zip(axes, names):
        j = result.joints.index(name)
        r = result.residual_series["after"][:, j]
        row[0].plot(seg.t, r, "b", lw=0.8)
        row[0].set_xlabel("t [s]", fontsize=8)
        row[0].set_ylabel(f"{name} residual [N·m]", fontsize=8)
        row[1].plot(seg.dtau[:, j], r, ".", ms=1.5)
        row[1].set_xlabel("dτ/dt [N·m/s]", fontsize=8)
        for ax in row:
            ax.tick_params(labelsize=7)
            ax.axhline(0, color="k", lw=0.5)
    fig.suptitle("Unexplained residual (augmented model) against time and dτ/dt")
    return save_figure(fig, path)


def _table(header: list[str], rows: list[list[Any]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(out + ["| " + " | ".join(str(x) for x in r) + " |" for r in rows])


def _g(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


def report_markdown(result, figures: list[str], model_files: list[str]) -> str:
    """The text of report.md: header and summary, then one section per step."""
    lines = _header(result) + _summary(result) + _cumulative(result) + _nominal_section(result)
    lines += _rigid_section(result) + _effects_section(result) + _augmented_section(result, model_files)
    lines += _unexplained_section(result, figures)
    return "\n".join(lines) + "\n"


def _header(r) -> list[str]:
    tr, ho = r.training, r.held_out
    rec = tr.record
    return [
        f"# Diagnosis of `{r.robot.name}`", "",
        f"- data: `{rec.source}`, {rec.rate_hz:.4g} Hz, zero-phase low-pass at {rec.cutoff_hz:.3g} Hz, "
        f"fitted at {rec.rate_hz / rec.step:.4g} Hz",
        f"- training: {tr.t[0]:.2f}–{tr.t[-1]:.2f} s ({tr.num_samples} samples); held-out: "
        f"{ho.t[0]:.2f}–{ho.t[-1]:.2f} s ({ho.num_samples} samples)"
        + (f" of `{ho.record.source}`" if ho.record is not rec else " (the end of the same record)"),
        "- all RMS values are on the held-out data [N·m]; the noise floor is the raw torque's white noise "
        "after the filter", "", "## Summary", ""]


def _summary(r) -> list[str]:
    lines = []
    if r.effects:
        lines += ["Named effects:", ""]
        lines.append(_table(["effect", "joint / link", "value", "± std", "unit", "z"],
                            [[e.effect, e.joint or e.link or "all joints", _g(e.value, 4), _g(e.std, 2), e.unit, _g(e.z, 3)]
                             for e in r.effects]))
        totals = [f"{e.effect}[{e.joint}] {_g(e.details['total'], 4)} {e.unit}" for e in r.effects
                  if "total" in (e.details or {})]
        if totals:  # issue 21: the fit starts from the URDF's <dynamics damping, friction>
            lines += ["", "A friction's value is what the model file's `<dynamics>` lacks; with it, the totals are: "
                      + ", ".join(totals) + "."]
    else:
        lines.append("No effect of the library is named: what the a-priori model misses is explained by the "
                     "rigid-body re-identification" + (" or left unexplained." if r.unexplained else "."))
    lines.append("")
    for ns in r.not_separable:
        if abs(ns.get("z_vs_prior", 0.0)) >= 5:
            lines += [f"Not separable but notable: {ns['effect']} of `{ns['joint']}` cannot be told apart from "
                      f"the rigid-body terms; the base parameter(s) it merges with changed as much as "
                      f"{_g(ns['implied_value_if_all'])} {ns['unit']} of it would ({_g(ns['z_vs_prior'])} × the "
                      "a-priori uncertainty). See section 3.", ""]
    if r.unexplained:
        lines += ["Unexplained: " + "; ".join(f"`{j}` {u['rms']:.3g} N·m ({u['hint']})"
                                              for j, u in r.unexplained.items()), ""]
    return lines


def _cumulative(r) -> list[str]:
    lines = ["![held-out gap](gap.png)", "", "## Cumulative held-out RMS per joint [N·m]", ""]
    rows = [[s] + [_g(v) for v in rms] for s, rms in r.cumulative]
    rows.append(["augmented Drake model"] + [_g(v) for v in r.rms_after])
    rows.append(["noise floor"] + [_g(v) for v in r.noise_floor])
    return lines + [_table(["step", *r.joints], rows), ""]


def _nominal_section(r) -> list[str]:
    lines = ["## 1. A-priori model along the measured motion", "",
             "Measured minus model torque, all samples (training and held-out): overall RMS and mean, the "
             "regime whose mean departs most, and the correlation with sign(v).", ""]
    rows = []
    for j in r.joints:
        g = r.regimes[j]
        s = g["strongest"]
        rows.append([j, _g(g["overall"]["rms"]), _g(g["overall"]["mean"]),
                     f"{s['regime']}: {s['bin']} (mean {_g(s['mean'])})", _g(g["correlation_sign_v"], 2),
                     _g(g["correlation_vd"], 2)])
    return lines + [_table(["joint", "RMS", "mean", "strongest regime", "corr sign(v)", "corr v̇"], rows), "",
                    "![regimes](regimes.png)", ""]


def _rigid_section(r) -> list[str]:
    lines = ["## 2. Rigid-body re-identification", ""]
    lines += [f"{r.rigid['count']} base parameters re-identified by weighted least squares. The largest "
              "changes from the a-priori model, in standard deviations of the a-priori uncertainty "
              f"({100 * r.config.prior_uncertainty:g} % per parameter) plus the estimate's:", ""]
    lines += [_table(["base parameter", "a-priori", "identified", "± std", "z vs prior"],
                     [[f"`{p['name'][:90]}`", _g(p["prior"], 4), _g(p["identified"], 4), _g(p["std"], 2),
                       _g(p["z_vs_prior"], 3)] for p in r.rigid["base_parameters"][:8]]), ""]
    pt = r.payload_test
    if pt.get("searched"):
        lines += [f"Payload search: χ² of the change vs the a-priori uncertainty {pt['chi2_before']:.3g} "
                  f"({pt['dof']} dof); {pt.get('decision', '')}"
                  + (f" (best link {pt['best_link']})" if pt.get("best_link") and "no payload" in
                     pt.get("decision", "") else "")
                  + (f"; explained as well on {', '.join(pt['equivalent_links'])} (a mass on a joint's "
                     "axis moves the same on either link)" if pt.get("equivalent_links") else "") + ".", ""]
    return lines


def _effects_section(r) -> list[str]:
    lines = ["## 3. Effects", ""]
    if r.effects:
        rows = []
        for e in r.effects:
            before = e.heldout_rms_before.get(e.joint) if e.joint else None
            after = e.heldout_rms_after.get(e.joint) if e.joint else None
            rows.append([e.effect, e.joint or e.link or "all joints", f"{_g(e.value, 4)} ± {_g(e.std, 2)} {e.unit}", _g(e.z),
                         f"{_g(before)} → {_g(after)}" if before is not None else "(within the rigid step)"])
        lines += [_table(["effect", "joint / link", "value", "z", "held-out RMS of its joint"], rows), ""]
    split = r.selection
    lines += ["Selection: forward stepwise on the training data alone, each effect physically plausible, "
              "significant after correcting for correlated samples, lowering its joint's cross-validated RMS "
              f"on the training data by ≥ {100 * r.config.min_heldout_gain:g} % and larger than "
              f"max({r.config.noise_factor:g} × noise floor, {100 * r.config.min_effect_fraction:g} % of the "
              "joint's torque spread); the held-out data give only the figures reported."
              + (f" Selection parts: {split['method']}, blocks of {_g(split['block_s'])} s, "
                 f"{_g(split['guard_s'])} s between a fold's fit and selection parts." if split else ""), ""]
    if r.not_separable:
        lines += ["Not separable from the rigid-body terms (not named; only their sum with a base parameter "
                  "is identifiable):", ""]
        for ns in r.not_separable:
            merged = ", ".join(f"`{k}`" for k in ns["merged_with"])
            extra = ""
            if "implied_value_if_all" in ns:
                extra = (f": all of the re-identified change of {'that' if len(ns['merged_with']) == 1 else 'those'}"
                         f" base parameter(s) as {ns['effect']} would be {_g(ns['implied_value_if_all'])} "
                         f"{ns['unit']} (a-priori uncertainty of that sum {_g(ns['implied_value_prior_std'])})")
            lines.append(f"- {ns['effect']} of `{ns['joint']}` merges with {merged}{extra}")
        lines.append("")
    decisions = r.decisions
    if decisions:
        lines += [f"Decisions: {decision_summary(decisions)} (every one in diagnosis.json `decisions`). "
                  "Closest to being named:", ""]
        lines += [_table(["effect", "joint", "value", "statistic", "test", "reason"],
                         [[d["effect"], d.get("joint") or d.get("link", ""),
                           f"{_g(d['value'])} {d['unit']}" if d.get("value") is not None else "",
                           _statistic(d), d["test"], d["reason"]] for d in near_misses(decisions, 6)]), ""]
    return lines + ["![residuals](residual_effects.png)", ""]


def decision_summary(decisions: Sequence[dict[str, Any]]) -> str:
    """One line: how many candidates were selected, rejected by which test, not separable."""
    counts = Counter(d["decision"] for d in decisions)
    tests = Counter(d["test"] for d in decisions if d["decision"] == "rejected")
    parts = [f"{counts.get('selected', 0)} selected",
             f"{counts.get('rejected', 0)} rejected"
             + (" (" + ", ".join(f"{k} {v}" for k, v in tests.most_common()) + ")" if tests else "")]
    parts += [f"{counts[k]} {k}" for k in (KEPT, "not separable", "not tried") if counts.get(k)]
    return f"{len(decisions)} candidates: " + ", ".join(parts)


def near_misses(decisions: Sequence[dict[str, Any]], count: int = 8) -> list[dict[str, Any]]:
    """The rejected candidates closest to being selected, the largest z / z_min first."""
    def closeness(d: dict[str, Any]) -> float:
        if d.get("test") == "sign":  # a negative friction or armature is far from being named
            return 0.0
        if d.get("z") is not None and d.get("z_min"):
            return float(d["z"]) / float(d["z_min"])
        if d.get("statistic") is not None and d.get("threshold"):
            return math.sqrt(max(float(d["statistic"]), 0.0) / float(d["threshold"]))  # a z²-like statistic
        return 0.0

    rejected = [d for d in decisions if d["decision"] == "rejected"]
    return sorted(rejected, key=closeness, reverse=True)[:count]


def _statistic(d: dict[str, Any]) -> str:
    """A decision's statistic against its threshold: z / z_min, or a χ²-like statistic."""
    if d.get("z") is not None and d.get("z_min") is not None:
        return f"z {_g(d['z'], 2)} (≥ {_g(d['z_min'], 2)})"
    if d.get("statistic") is not None and d.get("threshold") is not None:
        return f"{_g(d['statistic'], 3)} (≥ {_g(d['threshold'], 3)})"
    return ""


def _augmented_section(r, model_files: list[str]) -> list[str]:
    lines = ["## 4. Augmented model in Drake", ""]
    lines += ["The re-identified rigid-body parameters and the named effects, added to the Drake model (joint "
              "damping, rotor inertia, welded payload body, Coulomb friction as a `DoorHinge` force element, "
              "offsets as a generalized force); its inverse dynamics along the held-out motion:", ""]
    lines += [_table(["joint", "a-priori", "rigid", "augmented", "gap closed"],
                     [[j, _g(a), _g(b), _g(c), f"{100 * (1 - (c / a) ** 2):.1f} %" if a > 0 else "–"]
                      for j, a, b, c in zip(r.joints, r.rms_nominal, r.rms_rigid, r.rms_after)]), ""]
    lines.append("(gap closed: share of the a-priori model's held-out mean-square error removed.) Drake vs the "
                 "least-squares prediction: max " + _g(float(np.max(r.drake_check)), 2) + " N·m.")
    for note in r.augmented.notes:
        lines.append(f"- note: {note}")
    lines.append("")
    if model_files:
        lines += ["Files: " + ", ".join(f"`{f}`" for f in model_files)
                  + " (the URDF holds inertias, damping, rotor inertia and the payload; the YAML the Coulomb "
                    "friction and offsets, in the schema of `pe-drake simulate --truth`).", ""]
    return lines + ["![torques](torque_heldout.png)", ""]


def _unexplained_section(r, figures: list[str]) -> list[str]:
    lines = ["## 5. Unexplained", ""]
    if r.unexplained:
        rows = [[j, _g(u["rms"]), _g(u["threshold"]), _g(u["noise_floor"]),
                 f"{100 * u['fraction_of_nominal_rms']:.0f} %", u["hint"]] for j, u in r.unexplained.items()]
        lines += [_table(["joint", "RMS", "threshold", "noise floor", "of nominal RMS", "signature"], rows), ""]
        if "unexplained.png" in figures:
            lines += ["![unexplained](unexplained.png)", ""]
    else:
        lines += ["Every joint's held-out residual is below max("
                  f"{r.config.noise_factor:g} × noise floor, {100 * r.config.unexplained_fraction:g} % of its "
                  "torque spread).", ""]
    t = r.timing
    if t.get("checked"):
        state = "named as time_delay" if t.get("needed") else "not named"
        lines += [f"Timing check: a torque/position offset of {1e3 * t['offset_s']:+.3g} ± {1e3 * t['std_s']:.2g} ms "
                  f"fits the data ({state}; a logging offset, corrected for in the augmented model).", ""]
    return lines
