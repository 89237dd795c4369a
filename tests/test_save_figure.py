"""Figures are saved whole, in the format their suffix names, through a temporary file of an
unpredictable name (a symlink planted at the old fixed name ``.P.tmp.png`` is never followed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pe_drake.plots import save_figure  # noqa: E402


def _figure():
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    return fig


def test_planted_symlink_at_the_old_temporary_name_is_not_followed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / ".plot.png.tmp.png").symlink_to(victim)
    save_figure(_figure(), tmp_path / "plot.png")
    assert victim.read_text() == "keep me"
    assert (tmp_path / "plot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_format_follows_the_suffix_and_nothing_is_left_behind(tmp_path):
    save_figure(_figure(), tmp_path / "plot.pdf")
    save_figure(_figure(), tmp_path / "plot.svg")
    assert (tmp_path / "plot.pdf").read_bytes().startswith(b"%PDF")
    assert b"<svg" in (tmp_path / "plot.svg").read_bytes()[:400]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plot.pdf", "plot.svg"]
