"""`splatam info` on the real sequences in ../shared/data (skipped when the folder is absent):
each reads, has plausible depth units, and its reference poses pass the reprojection check."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
FOLDERS = sorted(p.name for p in DATA.iterdir() if p.is_dir()) if DATA.is_dir() else []

pytestmark = pytest.mark.realdata


@pytest.mark.skipif(not FOLDERS, reason=f"real data not found at {DATA}")
@pytest.mark.parametrize("name", FOLDERS or ["none"])
def test_info_on_real_sequence(name, capsys):
    from app.commands.info import format_text, gather
    from splat_core.io import open_capture

    src = open_capture(DATA / name)
    assert src.format_name == "tum"
    info = gather(src)
    print(format_text(info))
    assert info["depth"]["units_ok"], info["depth"]
    assert info["reference_poses"]
    pc = info["pose_check"]
    assert pc["ok"] is True, pc
    assert pc["median_abs_dz_m"] < 0.05  # centimetre-level: the right convention
    # the usual mistakes would be clearly worse
    assert min(pc["alternatives"].values()) > pc["median_abs_dz_m"]


@pytest.mark.skipif(not (DATA / "7scenes_redkitchen_300").is_dir(), reason="7-Scenes sample absent")
def test_7scenes_65535_is_invalid():
    import numpy as np

    from splat_core.io import open_capture

    src = open_capture(DATA / "7scenes_redkitchen_300")
    for i in range(0, len(src), 30):
        d = src[i].depth
        assert np.all(d < 65.0)  # 65535 mm would read as 65.5 m


@pytest.mark.slow
@pytest.mark.skipif(not FOLDERS, reason=f"real data not found at {DATA}")
@pytest.mark.parametrize("name", FOLDERS or ["none"])
def test_short_run_on_real_sequence(name, tmp_path):
    """`splatam run` end to end on the first frames of each real sequence (small settings)."""
    import json

    from app.cli import splatam_main

    cfg = tmp_path / "short.yaml"
    cfg.write_text("base: cpu\nresolution: [160, 120]\ntracking: {coarse_iterations: 0, iterations: 8}\n"
                   "mapping: {iterations: 3, first_frame_iterations: 10}\n")
    out = tmp_path / "run"
    assert splatam_main(["run", "--input", str(DATA / name), "--out", str(out), "--config", str(cfg),
                         "--max-frames", "3", "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == min(3, metrics["frames"]) and metrics["num_gaussians"] > 1000
    assert metrics["ate_rmse_cm"] is not None and metrics["ate_rmse_cm"] < 10
    assert (out / "map.ply").stat().st_size > 0
