"""Hand-offs (`splatam export --format colmap | nerfstudio | mesh`): the COLMAP model read back by
pycolmap, the nerfstudio dataset read with nerfstudio's conventions, both against exact synthetic
geometry (a camera-axis, handedness or half-pixel slip puts the back-projected depth off the
scene's planes), the tracks against the Gaussians, and the mesh against exact surfaces."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from app.cli import splatam_main
from splat_core.camera import invert_pose
from splat_core.config import load_config
from splat_core.export import write_colmap, write_nerfstudio
from splat_core.export.nerfstudio import nerfstudio_c2w
from splat_core.export.seed_points import project_points
from splat_core.io.ply import read_ply
from splat_core.run import Pipeline, open_input
from splat_core.refine.run_data import load_run_data, open_run_capture
from helpers import captures as fixtures
from helpers.scene import PLANES, make_sequence

# SLAM at 32x24 on a 64x48 capture: the exports re-read the capture at 64x48.
TINY = """base: cpu
resolution: [32, 24]
checkpoint_every: 0
keyframes: {every: 2}
tracking: {iterations: 4}
mapping: {iterations: 3, first_frame_iterations: 10, window_size: 4}
"""
N = 8


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("handoff")
    fixtures.write_tum(root / "cap", n=N)
    (root / "tiny.yaml").write_text(TINY)
    pipe = Pipeline(open_input(root / "cap"), load_config(str(root / "tiny.yaml")), root / "run")
    while pipe.step() is not None:
        pass
    pipe.finish()
    return root / "run"


def exact_run(run_dir):
    """The run with every pose replaced by the capture's exact one (in the run's world frame: the
    first frame's camera), so that exported geometry can be checked against the exact scene."""
    run = load_run_data(run_dir)
    ref = make_sequence(N, t0=1305031102.0).c2w
    first = ref[int(run.records[0]["source_index"])]
    exact = {k: invert_pose(invert_pose(first) @ ref[int(r["source_index"])]) for k, r in enumerate(run.records)}
    run.w2cs = [exact[k] for k in range(len(run.records))]
    for kf in run.keyframes:
        kf.w2c = exact[kf.frame_index]
    return run, first


def plane_distance(points_world):
    """Distance to the nearest of the fixture scene's planes (unbounded)."""
    return np.min([np.abs(points_world @ n - c) for n, c, _ in PLANES], axis=0)


def depth_of(run, name):
    source = open_run_capture(run)
    si = int(name.split("_")[1].split(".")[0])
    return source.frame_at_size(si, source.intrinsics.width, source.intrinsics.height).depth


# ----------------------------------------------------------------------------- COLMAP

def test_colmap_model_reads_back_with_exact_poses_and_geometry(finished_run, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    run, first = exact_run(finished_run)
    summary = write_colmap(run, tmp_path / "colmap")
    rec = pycolmap.Reconstruction(str(tmp_path / "colmap" / "sparse" / "0"))
    assert len(rec.images) == len(run.keyframes) == summary["images"]
    assert sorted(p.name for p in (tmp_path / "colmap" / "images").iterdir()) == sorted(i.name for i in rec.images.values())
    cam = rec.cameras[1]
    assert (cam.width, cam.height) == (64, 48)                      # the capture's resolution
    by_name = {f"frame_{int(run.records[kf.frame_index]['source_index']):06d}.jpg": kf for kf in run.keyframes}
    for image in rec.images.values():
        w2c = image.cam_from_world().matrix()
        assert np.abs(w2c - by_name[image.name].w2c[:3]).max() < 1e-6      # pose round trip
        # Pixel centres back-projected with pycolmap's own camera model land on the exact planes.
        depth = depth_of(run, image.name)
        v, u = np.nonzero(depth > 0)
        rays = cam.cam_from_img(np.stack([u + 0.5, v + 0.5], 1).astype(np.float64))   # COLMAP: centre of (0,0) is (0.5,0.5)
        pts_cam = np.concatenate([rays, np.ones((len(rays), 1))], 1) * depth[v, u, None]
        c2w = image.cam_from_world().inverse().matrix()
        world = (pts_cam @ c2w[:, :3].T + c2w[:, 3]) @ first[:3, :3].T + first[:3, 3]
        assert np.percentile(plane_distance(world), 99) < 3e-3


def test_colmap_tracks_reproject_onto_their_gaussians(finished_run, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    run = load_run_data(finished_run)
    write_colmap(run, tmp_path / "colmap", frames="all")
    rec = pycolmap.Reconstruction(str(tmp_path / "colmap" / "sparse" / "0"))
    assert len(rec.images) == N and len(rec.points3D) > 50
    means = run.map.to_numpy()["means"].astype(np.float64)
    cam = rec.cameras[1]
    intr = open_run_capture(run).intrinsics
    w2c_of = {f"frame_{int(r['source_index']):06d}.jpg": run.w2cs[k] for k, r in enumerate(run.records)}
    for kf in run.keyframes:
        w2c_of[f"frame_{int(run.records[kf.frame_index]['source_index']):06d}.jpg"] = kf.w2c
    for pid, point in rec.points3D.items():
        assert point.track.length() >= 1
        gaussian = means[np.abs(means - point.xyz).max(1).argmin()]
        assert np.abs(gaussian - point.xyz).max() < 1e-6                  # an exact Gaussian centre
        for el in point.track.elements:
            image = rec.images[el.image_id]
            xy = image.points2D[el.point2D_idx].xy
            assert image.points2D[el.point2D_idx].point3D_id == pid
            # where pycolmap projects the point, and where the Gaussian projects in the run
            # (camera.py's convention, pixel centres at integers; COLMAP's are at +0.5)
            assert np.linalg.norm(cam.img_from_cam(image.cam_from_world() * point.xyz) - xy) < 0.01
            u, v, _ = project_points(gaussian[None], w2c_of[image.name], intr)
            assert np.hypot(u[0] + 0.5 - xy[0], v[0] + 0.5 - xy[1]) < 0.01     # (the target: 1 px)


# ----------------------------------------------------------------------------- nerfstudio

def nerfstudio_backproject(meta, frame, depth_m):
    """World points of a depth image read the way nerfstudio does: rays through pixel (j + 0.5,
    i + 0.5) with OpenGL camera axes (y up, looking down -z), c2w = transform_matrix."""
    h, w = depth_m.shape
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    dirs = np.stack([(j - meta["cx"]) / meta["fl_x"], -(i - meta["cy"]) / meta["fl_y"], -np.ones_like(j)], -1)
    ok = depth_m > 0
    pts = dirs[ok] * depth_m[ok, None]            # camera z distance = depth (direction has |z| = 1)
    T = np.asarray(frame["transform_matrix"])
    return pts @ T[:3, :3].T + T[:3, 3]


def test_nerfstudio_dataset_round_trips_exact_poses(finished_run, tmp_path):
    run, first = exact_run(finished_run)
    write_nerfstudio(run, tmp_path / "ns", frames="all")
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and (meta["w"], meta["h"]) == (64, 48)
    assert len(meta["frames"]) == N
    for frame in meta["frames"]:
        T = np.asarray(frame["transform_matrix"])
        assert np.abs(T - nerfstudio_c2w(run.w2cs[frame["frame_index"]])).max() < 1e-6
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)        # a rotation, not a reflection
        raw = cv2.imread(str(tmp_path / "ns" / frame["depth_file_path"]), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16 and raw.shape == (48, 64)
        world = nerfstudio_backproject(meta, frame, raw * 1e-3) @ first[:3, :3].T + first[:3, 3]
        assert np.percentile(plane_distance(world), 99) < 3e-3
        assert cv2.imread(str(tmp_path / "ns" / frame["file_path"])).shape == (48, 64, 3)
    seeds = read_ply_points(tmp_path / "ns" / meta["ply_file_path"])
    assert 0 < len(seeds) <= len(run.map.to_numpy()["means"])


def test_a_slipped_axis_fails_the_nerfstudio_check(finished_run, tmp_path):
    """The check above is not vacuous: the same export with OpenCV axes left in place (or a
    handedness flip) puts the back-projected depth off the scene's planes."""
    run, first = exact_run(finished_run)
    write_nerfstudio(run, tmp_path / "ns", frames="keyframes")
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    frame = meta["frames"][-1]
    raw = cv2.imread(str(tmp_path / "ns" / frame["depth_file_path"]), cv2.IMREAD_UNCHANGED) * 1e-3
    for slip in (np.diag([1.0, -1.0, -1.0, 1.0]), np.diag([-1.0, 1.0, 1.0, 1.0]), np.diag([1.0, 1.0, -1.0, 1.0])):
        wrong = dict(frame, transform_matrix=(np.asarray(frame["transform_matrix"]) @ slip).tolist())
        world = nerfstudio_backproject(meta, wrong, raw) @ first[:3, :3].T + first[:3, 3]
        assert np.percentile(plane_distance(world), 99) > 0.05


def read_ply_points(path):
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    n = int(next(line for line in head.decode().splitlines() if line.startswith("element vertex")).split()[2])
    rec = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)], count=n)
    return rec["xyz"]


# ----------------------------------------------------------------------------- CLI and errors

def test_cli_exports_and_refuses_bad_input(finished_run, tmp_path, capsys):
    code = splatam_main(["export", str(finished_run), "--format", "nerfstudio", "--out", str(tmp_path / "ns"),
                         "--frames", "3", "--quiet"])
    assert code == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["images"] == 3 and (tmp_path / "ns" / "transforms.json").is_file()     # frames 0, 3, 6
    # Exporting again over a previous export replaces it; over anything else is refused.
    assert splatam_main(["export", str(finished_run), "--format", "nerfstudio", "--out", str(tmp_path / "ns"),
                         "--quiet"]) == 0
    assert len(json.loads((tmp_path / "ns" / "transforms.json").read_text())["frames"]) == len(
        load_run_data(finished_run).keyframes)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("mine")
    capsys.readouterr()
    for argv in (["--format", "colmap", "--out", str(tmp_path / "other")],
                 ["--format", "colmap", "--out", str(tmp_path / "c"), "--frames", "zero"],
                 ["--format", "nerfstudio", "--out", str(tmp_path / "c"), "--max-points", "0"],
                 ["--format", "mesh", "--out", str(tmp_path / "m.stl")]):
        assert splatam_main(["export", str(finished_run), "--quiet", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and "\n" not in err
    assert (tmp_path / "other" / "keep.txt").read_text() == "mine"
    assert not (tmp_path / "c").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]     # no temporary folders left


def test_a_run_without_its_capture_exports_its_keyframes(finished_run, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    run = load_run_data(run_dir)
    run.capture = None
    summary = write_nerfstudio(run, tmp_path / "ns")
    assert summary["size"] == [32, 24] and summary["images"] == len(run.keyframes)   # the stored keyframes
    with pytest.raises(Exception, match="--input"):
        write_nerfstudio(run, tmp_path / "ns2", frames="all")
