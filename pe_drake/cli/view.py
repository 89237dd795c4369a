"""``pe-drake view``: Meshcat playback of a trajectory, served or written as HTML."""

from __future__ import annotations

import time

from pe_drake.output_paths import check_output_file
from pe_drake.viewer import play_trajectory


def view_command(args) -> int:
    """``pe-drake view``: writes the HTML playback, or serves Meshcat until Ctrl-C."""
    start = time.perf_counter()
    if args.html:
        check_output_file(args.html, "--html", (".html", ".htm"))  # before any work
    playback = play_trajectory(args.trajectory, robot=args.robot, config=args.config,
                               html=args.html, show_capsules=not args.no_capsules, rate=args.rate,
                               host=getattr(args, "host", "localhost"),
                               trust_xacro=getattr(args, "trust_xacro", False))
    summary = (f"{playback.robot.name}: {playback.num_frames} frames over "
               f"{playback.duration:.3g} s ({playback.frames_per_second:.3g} fps)")
    if playback.capsule_file:  # which capsules are shown: the file to check and edit
        shown = "hidden" if args.no_capsules else "shown"
        summary += f"; {len(playback.robot.capsules)} capsules from {playback.capsule_file} ({shown})"
    if playback.html is not None:
        size = playback.html.stat().st_size / 1e6
        print(f"wrote {playback.html} ({size:.1f} MB; {summary}) in {time.perf_counter() - start:.1f} s")
        return 0
    plays = "the animation loops" if playback.loops else "the animation plays once, from rest to rest"
    print(f"Meshcat: {playback.url}  ({summary}; {plays}; Ctrl-C to quit)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        return 0
