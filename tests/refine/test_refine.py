"""`splatam refine`: held-out PSNR improves, resume equals an uninterrupted refine, density control,
bad input (one line, exit 2), and the viewer's Refine button."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from app.cli import splatam_main
from splat_core.config import MappingConfig, load_config
from splat_core.gaussians import GaussianMap
from splat_core.io.ply import read_ply
from splat_core.run import Pipeline, open_input
from splat_core.refine import RefineJob, RefineSettings
from splat_core.refine.density import DensitySettings, GradientStats, densify_and_prune
from helpers import captures as fixtures

# SLAM at 32x24 on a 64x48 capture: refinement at the capture's resolution has detail to add.
TINY = """base: cpu
resolution: [32, 24]
checkpoint_every: 0
keyframes: {every: 2}
tracking: {iterations: 4}
mapping: {iterations: 3, first_frame_iterations: 10, window_size: 4}
"""
FAST = dict(densify_from=10, densify_every=10)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("refine")
    fixtures.write_tum(root / "cap", n=10)
    (root / "tiny.yaml").write_text(TINY)
    pipe = Pipeline(open_input(root / "cap"), load_config(str(root / "tiny.yaml")), root / "run")
    while pipe.step() is not None:
        pass
    pipe.finish()
    return root / "run"


@pytest.fixture()
def run(finished_run, tmp_path):
    shutil.copytree(finished_run, tmp_path / "run")
    return tmp_path / "run"


def cli(args, capsys):
    code = splatam_main(args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_refine_improves_heldout_psnr_and_keeps_the_metrics(run, capsys):
    metrics_before = json.loads((run / "metrics.json").read_text())
    assert metrics_before["input"]["format"] == "tum"         # the run records its capture
    code, out, err = cli(["refine", str(run), "--iterations", "60", "--quiet"], capsys)
    assert code == 0, err
    metrics = json.loads((run / "metrics.json").read_text())
    section = metrics["refine"]
    assert {k: metrics[k] for k in metrics_before} == metrics_before      # existing content kept
    assert section["size"] == [64, 48] and section["iterations"] == 60
    assert section["heldout_frames"] == [2, 4, 6]            # not keyframes (0 1 3 5 7 8 9)
    assert section["after"]["psnr"] > section["before"]["psnr"] + 0.5, section
    assert section["after"]["depth_l1_cm"] < section["before"]["depth_l1_cm"]
    assert section["seconds_per_iteration"] > 0
    assert sum(d["cloned"] + d["split"] for d in section["densification"]) > 0
    refined = read_ply(run / "map_refined.ply")
    assert len(refined["means"]) == section["num_gaussians_after"]
    assert read_ply(run / "map.ply")["means"].shape[0] == metrics["num_gaussians"]   # map.ply untouched
    assert not (run / "refine_checkpoint").exists()
    assert json.loads(out.strip().splitlines()[-1])["after_psnr"] == section["after"]["psnr"]


def test_working_resolution_uses_the_stored_keyframes(run):
    job = RefineJob(run, RefineSettings(iterations=5), resolution="working")
    assert (job.intrinsics.width, job.intrinsics.height) == (32, 24)
    assert [v.color.shape for v in job.refiner.views] == [(24, 32, 3)] * 7
    for view, kf in zip(job.refiner.views, job.run.keyframes):
        assert np.array_equal(view.color.numpy(), kf.color) and np.array_equal(view.w2c, kf.w2c)


@pytest.mark.parametrize("anisotropic", [False, True])
def test_resume_equals_an_uninterrupted_refine(run, tmp_path, anisotropic):
    settings = RefineSettings(iterations=30, anisotropic=anisotropic, **FAST)
    other = tmp_path / "other"
    shutil.copytree(run, other)
    full = RefineJob(run, settings, checkpoint_every=0)
    while not full.done:
        full.step()
    full.finish()

    killed = RefineJob(other, settings, checkpoint_every=15)
    for _ in range(22):              # checkpoint after 15 (past a densification at 10); 16-22 lost
        killed.step()
    del killed
    resumed = RefineJob(other, settings, checkpoint_every=15)
    assert resumed.iteration == 15
    while not resumed.done:
        resumed.step()
    resumed.finish()
    assert (run / "map_refined.ply").read_bytes() == (other / "map_refined.ply").read_bytes()
    a, b = (json.loads((d / "metrics.json").read_text())["refine"] for d in (run, other))
    assert a["after"] == b["after"] and a["before"] == b["before"] and a["densification"] == b["densification"]
    # A checkpoint made with other settings is not silently resumed.
    again = RefineJob(other, settings, checkpoint_every=10)
    for _ in range(10):
        again.step()
    with pytest.raises(Exception, match="--restart"):
        RefineJob(other, RefineSettings(iterations=40, **FAST))


def test_anisotropic_refine_starts_from_the_same_gaussians_and_shapes_them(run, capsys):
    """`splatam refine --anisotropic`: the isotropic SLAM map gets three scales (the same Gaussians:
    held-out metrics before refining equal the isotropic map's), which the refine then shapes."""
    iso = RefineJob(run, RefineSettings(iterations=40), checkpoint_every=0).evaluate()
    aniso = RefineJob(run, RefineSettings(iterations=40, anisotropic=True), checkpoint_every=0)
    assert aniso.refiner.map.log_scales.shape[1] == 3
    assert aniso.evaluate()["psnr"] == pytest.approx(iso["psnr"], abs=1e-3)
    code, out, err = cli(["refine", str(run), "--iterations", "40", "--anisotropic", "--quiet"], capsys)
    assert code == 0, err
    section = json.loads((run / "metrics.json").read_text())["refine"]
    assert section["settings"]["anisotropic"] is True
    assert section["before"]["psnr"] == pytest.approx(iso["psnr"], abs=1e-3)
    assert section["after"]["psnr"] > section["before"]["psnr"] + 0.5, section
    scales = read_ply(run / "map_refined.ply")["log_scales"]
    assert scales.shape[1] == 3 and float(np.abs(scales[:, 0] - scales[:, 1]).max()) > 1e-3


def test_density_control_clones_small_and_splits_large_gaussians():
    m = GaussianMap.from_points(np.zeros((4, 3)) + [0, 0, 2], np.full((4, 3), 0.5), [0.001, 0.001, 0.1, 0.1], 3)
    opt = torch.optim.Adam(m.param_groups(MappingConfig().lrs), eps=1e-15)
    m.tensors().means.sum().backward()
    opt.step()
    stats = GradientStats(4)
    stats.grad_sum[:] = torch.tensor([1e-3, 1e-5, 1e-3, 1e-5], dtype=torch.float64)
    stats.count[:] = 1
    counts = densify_and_prune(m, opt, stats, DensitySettings(), MappingConfig(), scene_radius=1.0,
                               rng=np.random.default_rng(0))
    assert (counts["cloned"], counts["split"], counts["pruned"]) == (1, 1, 0)
    scales = torch.exp(m.log_scales.detach()).flatten().tolist()
    # kept in order (0, 1, 3), the clone of 0, then the two children of 2 at 0.1 / 1.6
    assert scales == pytest.approx([0.001, 0.001, 0.1, 0.001, 0.1 / 1.6, 0.1 / 1.6])
    assert len(m) == 6 and m.birth_frame.tolist() == [3] * 6
    assert not torch.allclose(m.means[4], m.means[5])        # children sampled apart
    state = opt.state[m.params["means"]]
    assert state["exp_avg"].shape == (6, 3) and float(state["exp_avg"][3:].abs().sum()) == 0.0


def test_bad_run_dir_is_one_line(tmp_path, capsys):
    code, _, err = cli(["refine", str(tmp_path / "nope")], capsys)
    assert code == 2 and err.count("\n") == 1 and "nope" in err and "Traceback" not in err
    (tmp_path / "empty").mkdir()
    code, _, err = cli(["refine", str(tmp_path / "empty")], capsys)
    assert code == 2 and err.count("\n") == 1 and "map.ply" in err


def test_viewer_refine_button_shows_the_map_while_refining_then_replaces_it(run):
    import viser

    from app.browse import load_run
    from app.viewer import StaticSource, build_viewer
    from helpers.viewer import click, wait_until

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    app = build_viewer(server, StaticSource(load_run(run)), render_backend="reference", update_hz=20)
    try:
        panel = app.refine_panel
        panel._publish_seconds = 0.0          # publish after every iteration
        wait_until(lambda: app.applied is not None and not panel.button.disabled, 60, what="Refine enabled")
        slam_count = app.applied.num_gaussians
        panel.iterations.value = 20
        click(panel.button)
        # the refine thread sets its result, publishes the map, then writes its summary and ends:
        # wait for the thread's end, not for the result, before reading the text
        wait_until(lambda: (panel.result is not None or panel.error) and not panel.running, 120,
                   what="refine to finish")
        assert panel.error is None and "Held-out PSNR" in panel.info.content
        refined = read_ply(run / "map_refined.ply")
        wait_until(lambda: app.applied.num_gaussians == len(refined["means"]) and np.array_equal(
            app.applied.gaussians["means"], refined["means"]), 60, what="the refined map shown")
        assert panel.result["num_gaussians_before"] == slam_count
        assert panel.published == 20                     # 19 while refining, the result at the end
        wait_until(lambda: not panel.button.disabled, 60, what="Refine enabled again")
    finally:
        app.close()
        server.stop()
