"""What a run reports: ATE against the reference, render metrics at the estimated poses, and the
figures of metrics.json (accuracy, speed, memory, what was skipped or lost)."""

from __future__ import annotations

import platform
import resource

import numpy as np
import torch

from .. import metrics as M
from ..camera import invert_pose, is_finite_pose


def ate_cm(estimated_c2w: np.ndarray, reference_c2w: np.ndarray | None) -> float | None:
    """ATE RMSE in cm over the frames with a reference pose (None: fewer than two); both (n, 4, 4)
    arrays (Pipeline.estimated_c2w_array, reference_c2w_array: NaN rows where a frame has none)."""
    if reference_c2w is None:
        return None
    n = min(len(estimated_c2w), len(reference_c2w))
    keep = np.flatnonzero(np.isfinite(reference_c2w[:n]).all(axis=(1, 2)))
    if len(keep) < 2:
        return None
    return 100.0 * float(M.ate_rmse(estimated_c2w[keep], reference_c2w[keep]))


def evaluate(render, w2cs: list, records: list[dict], frame_of, eval_every: int) -> dict:
    """PSNR, SSIM and depth L1 of the map rendered (`render(w2c)`, engine.render) at the estimated
    poses `w2cs` of frame 0 and every eval_every-th frame (`frame_of(k)`: processed frame k); lost
    frames are left out (a guess)."""
    picks = [k for k in range(len(records)) if M.is_evaluated(k, eval_every) and not records[k].get("lost")]
    psnrs, ssims, depth_l1s = [], [], []
    for k in picks:
        frame = frame_of(k)
        out = render(w2cs[k])
        color = torch.as_tensor(frame.color, device=out.color.device)
        depth = torch.as_tensor(frame.depth, device=out.depth.device)
        psnrs.append(float(M.psnr(out.color, color)))
        ssims.append(float(M.ssim_metric(out.color, color)))
        depth_l1s.append(float(M.depth_l1(out.depth, depth)))
    mean = lambda xs: float(np.mean(xs)) if xs else None  # noqa: E731
    return dict(eval_frames=picks, psnr=mean(psnrs), ssim=mean(ssims),
                depth_l1_cm=None if not depth_l1s else 100.0 * mean(depth_l1s))


def summary(pipe) -> dict:
    """metrics.json's summary of a Pipeline (without the engine's stats and the render metrics)."""
    from .frame_feed import input_record

    records, engine = pipe.records, pipe.engine
    w2cs = engine.trajectory()
    track = [r["tracking_seconds"] for r in records]
    mapping = [r["mapping_seconds"] for r in records]
    wall = [r["wall_seconds"] for r in records]
    cpu = [r.get("cpu_seconds") for r in records]
    out = dict(
        engine=pipe.engine_name, frames=len(records), frames_skipped=len(pipe.skipped),
        skipped=pipe.skipped, frames_lost=len(pipe.lost), lost=pipe.lost,
        frames_without_reference=sum(not is_finite_pose(r) for r in pipe.references) if pipe.has_reference() else 0,
        num_gaussians=engine.num_gaussians(), keyframes=len(engine.keyframes()),
        ate_rmse_cm=pipe.ate_cm(),
        tracking_seconds_per_frame=float(np.mean(track)) if track else None,
        mapping_seconds_per_frame=float(np.mean(mapping)) if mapping else None,
        seconds_per_frame=float(np.mean(np.add(track, mapping))) if track else None,
        wall_seconds_per_frame=float(np.mean(wall)) if wall else None,
        wall_seconds_per_frame_median=float(np.median(wall[1:])) if len(wall) > 1 else None,
        # CPU seconds of the whole process (every thread, both cores) per frame, the end included: what
        # the frames cost whatever else shares the machine (records of runs before it was kept: none)
        cpu_seconds_per_frame=float(np.mean(cpu)) if cpu and None not in cpu else None,
        peak_memory_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        device=str(pipe.device), machine=platform.processor() or platform.machine(),
        resolution=[pipe.intrinsics.width, pipe.intrinsics.height], config=pipe.config.name,
        intrinsics=pipe.intrinsics.to_dict(), input=input_record(pipe.source),
    )
    refs = pipe.reference_c2w()
    if refs is not None:
        pairs = [(w, invert_pose(r)) for w, r in zip(w2cs, refs) if r is not None]
        if len(pairs) >= 2:
            est, ref = zip(*pairs)
            out["ate_mean_legacy_cm"] = 100.0 * float(M.ate_mean_legacy(np.array(est), np.array(ref)))
    if pipe.streaming:
        out.update(pipe.source.stats())   # received, dropped (never given to SLAM), rejected
    if pipe.device.type == "cuda":
        out["peak_gpu_memory_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return out
