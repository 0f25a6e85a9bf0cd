"""Hand-offs of a two-camera capture describe the colour camera (splat_core/export/color_camera.py):
on the synthetic two-camera capture (splat_core/synthetic/two_cameras.py, colour rendered exactly from its
own camera), the COLMAP model read back by pycolmap and nerfstudio's transforms.json carry the
colour camera's intrinsics, poses, images and depth; the seed points stay in the run's world."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from helpers.two_cameras import write_two_camera_tum
from splat_core.camera import invert_pose
from splat_core.config import load_config
from splat_core.export import write_colmap, write_nerfstudio
from splat_core.export.nerfstudio import OPENCV_TO_OPENGL
from splat_core.export.frames import write_color
from splat_core.export.seed_points import seed_points
from splat_core.io.images import read_color
from splat_core.refine.run_data import load_run_data
from splat_core.run import Pipeline, open_input

TINY = """base: cpu
resolution: [40, 30]
checkpoint_every: 0
keyframes: {every: 2}
tracking: {iterations: 4}
mapping: {iterations: 3, first_frame_iterations: 10, window_size: 4}
"""
N = 6


@pytest.fixture(scope="module")
def two_camera_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("two_handoff")
    cap = write_two_camera_tum(root / "cap", n=N, width=80, height=60)
    (root / "tiny.yaml").write_text(TINY)
    pipe = Pipeline(open_input(root / "cap"), load_config(str(root / "tiny.yaml")), root / "run")
    assert pipe.source.two_cameras is not None
    while pipe.step() is not None:
        pass
    pipe.finish()
    return cap, root / "run"


def exact_run(cap, run_dir):
    """The run with the depth camera's exact poses, in the run's world (the first frame's camera);
    returns it and the exact colour-camera w2c of each capture frame in that world."""
    run = load_run_data(run_dir)
    first = cap.source.c2w[cap.frames[int(run.records[0]["source_index"])]]
    depth_w2c = {k: invert_pose(invert_pose(first) @ cap.source.c2w[cap.frames[int(r["source_index"])]])
                 for k, r in enumerate(run.records)}
    run.w2cs = [depth_w2c[k] for k in range(len(run.records))]
    for kf in run.keyframes:
        kf.w2c = depth_w2c[kf.frame_index]
    color_w2c = {si: invert_pose(invert_pose(first) @ cap.color_c2w(f)) for si, f in enumerate(cap.frames)}
    return run, color_w2c


def seen_by_depth_camera(color_depth, kc, cap, max_depth, margin=1.0):
    """Colour pixels whose exact point lies in the depth camera's view (more than `margin` pixels
    inside its image: a negative margin, outside), nearer than max_depth."""
    v, u = np.mgrid[0:kc.height, 0:kc.width]
    z = color_depth
    p = np.stack([(u - kc.cx) / kc.fx * z, (v - kc.cy) / kc.fy * z, z], -1) - cap.translation   # p_depth = p_color - t
    k = cap.depth_intr
    ud, vd = k.fx * p[..., 0] / p[..., 2] + k.cx, k.fy * p[..., 1] / p[..., 2] + k.cy
    return (z > 0) & (p[..., 2] <= (max_depth or np.inf)) & (ud >= margin - 0.5) & (vd >= margin - 0.5) & (ud <= k.width - 0.5 - margin) & (vd <= k.height - 0.5 - margin)


def source_index(name: str) -> int:
    return int(name.split("_")[1].split(".")[0])


def test_colmap_model_is_the_colour_cameras(two_camera_run, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    cap, run_dir = two_camera_run
    run, color_w2c = exact_run(cap, run_dir)
    summary = write_colmap(run, tmp_path / "colmap", frames="all")
    rec = pycolmap.Reconstruction(str(tmp_path / "colmap" / "sparse" / "0"))
    cam = rec.cameras[1]
    kc = cap.color_intr
    assert (cam.width, cam.height) == (kc.width, kc.height) and summary["images"] == N
    np.testing.assert_allclose(cam.params, [kc.fx, kc.fy, kc.cx + 0.5, kc.cy + 0.5], atol=1e-9)
    assert kc.fx != pytest.approx(cap.depth_intr.fx, rel=0.05)         # the two cameras differ
    n_obs = 0
    for image in rec.images.values():
        si = source_index(image.name)
        assert np.abs(image.cam_from_world().matrix() - color_w2c[si][:3]).max() < 1e-6
        # the image is the colour file as stored, encoded as every export image is
        stored = read_color(cap.path / f"rgb/{cap.frames[si] / 30.0:.6f}.png")
        write_color(tmp_path / "stored.jpg", stored)
        assert (tmp_path / "colmap" / "images" / image.name).read_bytes() == (tmp_path / "stored.jpg").read_bytes()
        # tracks: each point's observation is where pycolmap projects it in the colour camera
        for p2d in image.points2D:
            if p2d.has_point3D():
                xyz = rec.points3D[p2d.point3D_id].xyz
                assert np.linalg.norm(cam.img_from_cam(image.cam_from_world() * xyz) - p2d.xy) < 0.01
                n_obs += 1
    assert n_obs > 50


def test_nerfstudio_dataset_is_the_colour_cameras(two_camera_run, tmp_path):
    cap, run_dir = two_camera_run
    run, color_w2c = exact_run(cap, run_dir)
    write_nerfstudio(run, tmp_path / "ns", frames="all")
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    kc = cap.color_intr
    assert (meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]) == pytest.approx((kc.fx, kc.fy, kc.cx + 0.5, kc.cy + 0.5))
    assert (meta["w"], meta["h"]) == (kc.width, kc.height) and len(meta["frames"]) == N
    for frame in meta["frames"]:
        si = frame["source_index"]
        assert frame["file_path"] == f"images/frame_{si:06d}.jpg"
        expected = invert_pose(color_w2c[si]) @ OPENCV_TO_OPENGL
        assert np.abs(np.asarray(frame["transform_matrix"]) - expected).max() < 1e-6
        # depth seen from the colour camera: its exact render, where a depth pixel landed
        _, exact = cap.source.scene.render(cap.color_c2w(cap.frames[si]), kc)
        depth = cv2.imread(str(tmp_path / "ns" / frame["depth_file_path"]), cv2.IMREAD_UNCHANGED) * 1e-3
        assert depth.shape == (kc.height, kc.width)
        seen = seen_by_depth_camera(exact, kc, cap, run.config.max_depth)
        unseen = ~seen_by_depth_camera(exact, kc, cap, run.config.max_depth, margin=-1.0)
        assert seen.mean() > 0.5 and unseen.mean() > 0.05       # the colour camera sees more than the depth camera
        assert (depth > 0)[seen].mean() > 0.95 and (depth > 0)[unseen].mean() < 0.02
        both = (depth > 0) & seen
        rel = np.abs(depth[both] - exact[both]) / exact[both]      # (millimetres; a point lands up to half a pixel off)
        assert np.median(rel) < 0.005 and np.quantile(rel, 0.9) < 0.02   # (the rest: silhouettes)
    # the seed points are the map's, in the run's world (not moved into any camera)
    ply = (tmp_path / "ns" / meta["ply_file_path"]).read_bytes()
    n = int(ply.split(b"element vertex ")[1].split(b"\n")[0])
    xyz = np.frombuffer(ply.split(b"end_header\n", 1)[1], dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)], count=n)["xyz"]
    np.testing.assert_allclose(xyz, seed_points(run.map.to_numpy()).xyz, atol=1e-5)


def test_a_registered_captures_handoff_keeps_the_depth_camera(tmp_path):
    """The same scene with one camera (colour rendered from the depth camera): the export's camera
    is the capture's, as before."""
    cap = write_two_camera_tum(tmp_path / "one", n=3, width=80, height=60, ratio=1.0, translation=[0.0, 0.0, 0.0])
    source = open_input(cap.path)
    assert source.two_cameras is None
    from splat_core.export.frames import export_intrinsics

    assert export_intrinsics(None, source) == source.intrinsics == cap.depth_intr


def test_a_run_registered_from_its_estimate_hands_off_the_estimated_colour_camera(tmp_path):
    """The camera file only says colour and depth are not registered (as 7-Scenes'): the run
    registered the capture from its own estimate, and the export re-opens it the same way."""
    cap = write_two_camera_tum(tmp_path / "raw", n=4, width=80, height=60, describe=False)
    (tmp_path / "tiny.yaml").write_text(TINY)
    pipe = Pipeline(open_input(cap.path), load_config(str(tmp_path / "tiny.yaml")), tmp_path / "run")
    assert pipe.source.two_cameras is not None
    while pipe.step() is not None:
        pass
    pipe.finish()
    write_nerfstudio(load_run_data(tmp_path / "run"), tmp_path / "ns")
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    assert meta["fl_x"] == pytest.approx(cap.color_intr.fx, rel=0.01)
    assert meta["fl_x"] != pytest.approx(cap.depth_intr.fx, rel=0.05)
