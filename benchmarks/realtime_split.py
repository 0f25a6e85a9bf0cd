"""Where a real-time playback's time went (`--realtime`), from its metrics.json: the capture frames
between processed ones (the gaps), and the seconds between handed-over frames split into tracking
(frames tracked from the prediction), relocalisation (frames lost or relocalised: tracking_seconds of
those), the tracker's waits for the mapper (live engine: per-frame mapping_seconds), and the rest
(reading the frame, the pipeline, waiting for a frame to arrive); with keyframes, keyframes deferred
(`live.keyframes_deferred`, live.pace_keyframes) and frames lost.

    python benchmarks/live_rate.py --sequences 7scenes_redkitchen_300 --max-frames 300 --work DIR
    python benchmarks/realtime_split.py DIR/*__rt*

Frame 0 (mapped before the playback's clock starts) and the final drain are left out of the sums.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def split(run: Path) -> dict:
    m = json.loads((run / "metrics.json").read_text())
    pf = m["per_frame"][1:]                 # frame 0: mapped before the clock starts
    if not pf:
        return dict(run=run.name, frames=len(m["per_frame"]))
    source = np.array([r["source_index"] for r in m["per_frame"]])
    wall = np.array([r["wall_seconds"] for r in pf])
    wall[-1] = np.nan if len(pf) > 1 else wall[-1]      # the last frame's wall includes the final drain
    track = np.array([r["tracking_seconds"] for r in pf])
    wait = np.array([r["mapping_seconds"] for r in pf])
    relocalising = np.array([bool(r.get("lost")) or r.get("tracking_start") == "relocalised" for r in pf])
    body = slice(0, len(pf) - 1) if len(pf) > 1 else slice(0, 1)
    gaps = np.diff(source)
    live = m.get("live", {})
    return dict(run=run.name, frames=m["frames"], received=m.get("received"), gap_median=float(np.median(gaps)),
                gap_max=int(gaps.max()), seconds=float(np.nansum(wall[body])),
                tracking=float(track[body][~relocalising[body]].sum()),
                relocalising=float(track[body][relocalising[body]].sum()), waits=float(wait[body].sum()),
                rest=float(np.nansum((wall - track - wait)[body])),
                track_median=float(np.median(track[~relocalising])) if (~relocalising).any() else float("nan"),
                keyframes=m.get("keyframes"), deferred=live.get("keyframes_deferred"), lost=m.get("frames_lost"),
                ate=m.get("ate_rmse_cm"))


def main() -> None:
    print("| run | frames of received | gap median / max (capture frames) | seconds (frames 1 to last-1) | "
          "tracking | relocalising | waits for the mapper | rest | tracking median s | keyframes | deferred | "
          "lost | ATE cm |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for arg in sys.argv[1:]:
        r = split(Path(arg))
        if "seconds" not in r:
            print(f"| {r['run']} | {r['frames']} |||||||||||")
            continue
        deferred = "–" if r["deferred"] is None else r["deferred"]
        print(f"| {r['run']} | {r['frames']} of {r['received']} | {r['gap_median']:g} / {r['gap_max']} | "
              f"{r['seconds']:.1f} | {r['tracking']:.1f} | {r['relocalising']:.1f} | {r['waits']:.1f} | "
              f"{r['rest']:.1f} | {r['track_median']:.3f} | {r['keyframes']} | {deferred} | {r['lost']} | "
              f"{r['ate']:.2f} |")


if __name__ == "__main__":
    main()
