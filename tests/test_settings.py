"""Settings in two layers (budget + format layer) and the working resolution that fits the capture."""

from __future__ import annotations

import argparse
import dataclasses
import json

import cv2
import numpy as np
import pytest
import yaml

from helpers import captures as fixtures
from app.cli import splatam_main
from splat_core import config as C
from splat_core.config import load_config
from splat_core.errors import InputError
from splat_core.io.detect import FORMATS
from splat_core.run import Pipeline
from splat_core.run.resolution import capture_size, parse_resolution, working_size
from splat_core.synthetic import SyntheticPhoneCapture

BUDGETS = ("cpu", "cpu_dense", "splatam", "splatam_s")
SOURCE_FORMATS = (*FORMATS, "synthetic", "nerfcapture-stream")
TINY = "base: cpu\nresolution: [64, 48]\ncheckpoint_every: 0\ntracking: {iterations: 2}\n" \
       "mapping: {iterations: 2, first_frame_iterations: 4, window_size: 4}\n"


def test_a_presets_resolution_keeps_the_captures_aspect():
    assert working_size([320, 240], 640, 480) == (320, 240)            # the benchmark presets' size
    assert working_size([320, 240], 1920, 1440) == (320, 240)
    assert working_size([320, 240], 480, 640) == (240, 320)            # portrait stays portrait
    assert working_size([320, 240], 192, 256) == (192, 256)            # never above the capture
    w, h = working_size([320, 240], 1200, 680)                         # Replica: 320x240 pixels, 1200:680
    assert abs(w / h - 1200 / 680) < 0.01 and abs(w * h - 320 * 240) < 400
    assert working_size(320, 720, 960) == (240, 320)                    # a long side
    assert working_size(None, 1200, 680) == (1200, 680)
    assert capture_size((1920, 1440), (256, 192), 1.0) == (256, 192)   # phones: colour shrunk to the depth grid
    assert capture_size((1920, 1440), (256, 192), 1.25) == (320, 240)
    assert capture_size((1920, 1440), (256, 192), None) == (1920, 1440)
    assert parse_resolution("native") is None and parse_resolution("320") == 320
    assert parse_resolution("320x240") == [320, 240]
    for bad in ("0", "320x", "big", "-3x2"):
        with pytest.raises(InputError, match="--resolution"):
            parse_resolution(bad)


def test_phone_frames_come_from_their_own_grids_portrait_kept():
    phone = SyntheticPhoneCapture(3, color_size=(96, 128), depth_size=(24, 32))   # portrait, depth 4x smaller
    pipe = Pipeline(phone, load_config("cpu", {"resolution": [32, 24]}))
    assert (pipe.intrinsics.width, pipe.intrinsics.height) == (24, 32)             # at the depth grid
    pipe = Pipeline(phone, load_config("cpu", {"resolution": [64, 48], "depth_upsampling": 2.0}))
    assert (pipe.intrinsics.width, pipe.intrinsics.height) == (48, 64)
    frame = pipe.frame_at(0)
    color, depth = phone._render(0)
    assert np.allclose(frame.color, cv2.resize(color, (48, 64), interpolation=cv2.INTER_AREA), atol=1e-6)
    assert np.array_equal(frame.depth, np.repeat(np.repeat(depth, 2, axis=0), 2, axis=1))   # nearest, once
    assert np.isclose(frame.intrinsics.fx, phone.intrinsics.scaled(48, 64).fx)


def test_every_format_has_a_layer_and_budgets_keep_their_iterations():
    for budget in BUDGETS:
        alone = load_config(budget)
        for fmt in SOURCE_FORMATS:
            c = load_config(budget, format=fmt)
            assert c.format_layer == C.FORMAT_ALIASES.get(fmt, fmt), (budget, fmt)
            for part in ("tracking", "mapping", "densify", "live"):
                assert getattr(c, part) == getattr(alone, part), (budget, fmt, part)
            assert c.resolution == alone.resolution and c.scene_radius_depth_ratio == alone.scene_radius_depth_ratio
    for path in (C.CONFIG_DIR / "formats").glob("*.yaml"):
        assert set(yaml.safe_load(path.read_text()) or {}) <= set(C.FORMAT_KEYS), path
    phone = load_config("cpu", format="record3d")
    assert phone.max_depth == 5.0 and phone.min_confidence == 2 and load_config("cpu", format="tum").max_depth is None


def test_a_format_layer_may_not_set_budget_keys(tmp_path, monkeypatch):
    (tmp_path / "formats").mkdir()
    (tmp_path / "cpu.yaml").write_text("tracking: {iterations: 2}\n")
    (tmp_path / "formats" / "tum.yaml").write_text("max_depth: 4.0\ntracking: {iterations: 200}\n")
    monkeypatch.setattr(C, "CONFIG_DIR", tmp_path)
    with pytest.raises(InputError, match="format layer may set only.*not tracking"):
        load_config("cpu", format="tum")


def test_paper_presets_and_explicit_layers():
    tum = load_config("splatam_tum", format="tum")
    assert (tum.tracking.iterations, tum.mapping.iterations, tum.mapping.window_size) == (200, 30, 20)
    assert tum.scene_radius_depth_ratio == 2.0 and tum.format_layer == "tum"
    phone = load_config("splatam_iphone", format="strayscanner")
    assert phone.tracking.iterations == 60 and phone.depth_upsampling == 4.0 and phone.max_depth == 5.0
    assert "replaced by splatam_iphone" in C.describe_layers(phone)
    # A layer named in --config replaces the detected one (a phone capture converted to TUM).
    named = load_config("cpu+record3d", format="tum")
    assert named.format_layer == "record3d" and named.max_depth == 5.0
    assert named.tracking == load_config("cpu").tracking


def test_run_applies_and_records_the_format_layer(tmp_path, capsys):
    fx = fixtures.write_record3d(tmp_path / "scan", n=3)        # portrait: colour 720x960, depth 192x256
    (tmp_path / "tiny.yaml").write_text(TINY)
    out = tmp_path / "run"
    assert splatam_main(["run", "--input", str(fx.path), "--out", str(out), "--config", str(tmp_path / "tiny.yaml"),
                         "--resolution", "40", "--min-confidence", "1", "--max-frames", "2"]) == 0
    err = capsys.readouterr().err
    assert "format layer record3d (max_depth 5.0, min_confidence 1 (the layer's 2" in err
    assert "frames at 30x40 (colour 720x960, depth 192x256)" in err
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["format_layer"] == "record3d" and saved["name"].endswith("tiny.yaml")
    assert saved["resolution"] == 40 and saved["min_confidence"] == 1 and saved["max_depth"] == 5.0
    assert json.loads((out / "metrics.json").read_text())["resolution"] == [30, 40]
    # Resuming with other settings is refused: the checkpoint holds the resolved config.
    assert splatam_main(["run", "--input", str(fx.path), "--out", str(out), "--config", str(tmp_path / "tiny.yaml"),
                         "--max-frames", "2", "--resume", "--quiet"]) == 2
    assert "another config" in capsys.readouterr().err


def test_viewer_sets_its_run_up_with_the_same_function(tmp_path):
    from app.commands.viewer import add_arguments
    from app.run_setup import setup_from_args

    fx = fixtures.write_record3d(tmp_path / "scan", n=2)
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--input", str(fx.path), "--resolution", "48x64", "--min-confidence", "0",
                         "--config", "cpu"])
    run = setup_from_args(args, out=tmp_path / "run")
    assert run.engine == "live" and run.source.min_confidence == 0 and run.config.format_layer == "record3d"
    pipe = run.start()
    assert (pipe.intrinsics.width, pipe.intrinsics.height) == (48, 64)
    lines = run.lines()
    assert lines[0].startswith("record3d capture") and "budget cpu + format layer record3d" in lines[1]
    with pytest.raises(InputError, match="no LiDAR confidence"):
        setup_from_args(p.parse_args(["--min-confidence", "1"]), out=tmp_path / "synth")


def test_info_says_which_layers_apply(tmp_path, capsys):
    fx = fixtures.write_strayscanner(tmp_path / "stray", n=3)
    assert splatam_main(["info", "--input", str(fx.path), "--config", "splatam_s", "--json"]) == 0
    st = json.loads(capsys.readouterr().out)["settings"]
    assert st["budget"] == "splatam_s" and st["format_layer"] == "strayscanner"
    assert st["format_settings"]["max_depth"] == 5.0 and st["tracking_iterations"] == 10
    layer = load_config("splatam_s", format="strayscanner").depth_upsampling      # native, at most that x the grid
    assert st["working_size"] == list(capture_size((1920, 1440), (256, 192), layer))
    assert splatam_main(["info", "--input", str(fx.path), "--config", "cpu", "--resolution", "160"]) == 0
    text = capsys.readouterr().out
    assert "settings     budget cpu + format layer strayscanner" in text and "at 160x120" in text


def test_config_yaml_round_trips_with_both_layers(tmp_path):
    c = load_config("cpu", format="nerfcapture")
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(c.to_dict(), sort_keys=False))
    again = load_config(str(path), format="nerfcapture")
    assert dataclasses.replace(again, name=c.name).to_dict() == c.to_dict()
