"""PSNR of a run's final map at its estimated poses, per evaluated frame (frame 0 and every 5th, as
metrics.json's `psnr` averages them): which part of a sequence a PSNR difference comes from.

    python benchmarks/psnr_per_frame.py ../shared/data/sun3d_3dmatch_fragment2 RUN_A RUN_B ...
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    from app.browse import near_plane_of
    from app.video import gaussians_of
    from splat_core import metrics as M
    from splat_core.camera import invert_pose
    from splat_core.io.detect import open_capture
    from splat_core.io.map_files import map_path_of, read_map_file
    from splat_core.io.trajectory import read_tum_trajectory
    from splat_core.render import Renderer
    from splat_core.run.frame_feed import prepare_frame
    from splat_core.run.run_folder import RunFolder

    source = open_capture(sys.argv[1])
    for arg in sys.argv[2:]:
        run = Path(arg)
        intr = RunFolder(run).intrinsics()
        g = gaussians_of(read_map_file(map_path_of(run)), "cpu")
        _, c2ws = read_tum_trajectory(run / "trajectory.txt")
        renderer = Renderer(near_plane_of(run))
        picks = [k for k in range(len(c2ws)) if k == 0 or (k + 1) % 5 == 0]
        psnrs = []
        for k in picks:
            frame = prepare_frame(source, k, intr, None)
            with torch.no_grad():
                out = renderer.render_visible(g, intr, invert_pose(c2ws[k]))
            psnrs.append(float(M.psnr(out.color, torch.as_tensor(frame.color))))
        print(f"{run.name}: mean {np.mean(psnrs):.2f} dB | " + " ".join(f"{k}:{p:.1f}" for k, p in zip(picks, psnrs)))


if __name__ == "__main__":
    main()
