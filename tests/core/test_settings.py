"""Settings in two layers (budget + format layer) and the working resolution that fits the capture."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json

import cv2
import numpy as np
import pytest
import yaml

from helpers import captures as fixtures
from app.cli import SUBCOMMANDS, splatam_main
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
        assert set(yaml.safe_load(path.read_text()) or {}) <= {*C.FORMAT_KEYS, "base"}, path
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


@pytest.mark.parametrize("text, message", [
    ("tracking: {iterations: ten}", "tracking.iterations = 'ten': expected an integer"),
    ("tracking: {lr_rotation: fast}", "tracking.lr_rotation = 'fast': expected a number"),
    ("tracking: {lr_rotation: 1e-3}", "tracking.lr_rotation = '1e-3': expected a number (YAML reads this as text"),
    ("mapping: {iterations: true}", "mapping.iterations = True: expected an integer"),
    ("mapping: {iterations: 2.5}", "mapping.iterations = 2.5: expected an integer"),
    ("tracking: {pixels: some}", "tracking.pixels = 'some': expected one of all, random, gradient, depth_edges"),
    ("tracking: {align: {backend: cuda}}", "tracking.align.backend = 'cuda': expected one of auto, numba, torch"),
    ("loop_closure: {enabled: 1}", "loop_closure.enabled = 1: expected true or false"),
    ("max_depth: far", "max_depth = 'far': expected a number or null"),
    ("resolution: [320, big]", "resolution = [320, 'big']: expected a list of integers, an integer or null"),
    ("mapping: {lrs: {means: x}}", "mapping.lrs.means = 'x': expected a number"),
    ("keyframes: 5", "keyframes = 5: expected a mapping"),
    ("base: 3", "base = 3: expected a string"),
])
def test_a_value_of_the_wrong_type_is_one_error_naming_file_key_value_and_type(tmp_path, capsys, text, message):
    path = tmp_path / "my.yaml"
    path.write_text(f"base: cpu\n{text}\n" if not text.startswith("base") else text + "\n")
    with pytest.raises(InputError) as error:
        load_config(str(path))
    assert str(error.value).startswith(f"{path}: {message}")
    # the CLI prints it as one line, no traceback
    assert splatam_main(["config", "show", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: {message}") and err.count("\n") == 1


def test_right_types_pass_ints_serve_as_numbers_and_keep_their_value():
    c = load_config("cpu", {"depth_upsampling": 2, "max_depth": None, "tracking": {"lr_rotation": 1},
                            "resolution": 200, "mapping": {"lrs": {"means": 1}}})
    assert c.depth_upsampling == 2 and type(c.depth_upsampling) is int and c.mapping.lrs["means"] == 1
    assert load_config("cpu", {"resolution": [64, 48]}).resolution == [64, 48]
    with pytest.raises(InputError, match=r"overrides: tracking\.iterations = '3': expected an integer"):
        load_config("cpu", {"tracking": {"iterations": "3"}})
    with pytest.raises(InputError, match="mapping.window_size must be >= 2"):       # range checks stay
        load_config("cpu", {"mapping": {"window_size": 1}})
    with pytest.raises(InputError, match=r"mapping.first_frame_tile_fraction must be in \(0, 1\]"):
        load_config("live", {"mapping": {"first_frame_tile_fraction": 0}})


def test_every_shipped_preset_and_default_fits_the_schema():
    from splat_core.config_schema import accepts, leaves
    from splat_core.settings_doc import resolved

    for name in C.preset_names():
        config = load_config(name)
        for key, f, hint in leaves(C.Config):
            assert accepts(resolved(config, key), hint), (name, key)
            assert f.metadata.get("doc"), key                  # every key is documented beside its field


def test_strayscanner_layer_is_record3ds():
    stray, r3d = (C.format_layer_path(n) for n in ("strayscanner", "record3d"))
    assert yaml.safe_load(stray.read_text()) == {"base": "record3d"}
    assert C.format_layer_settings("strayscanner") == C.format_layer_settings("record3d") == \
        {"max_depth": 5.0, "min_confidence": 2, "depth_upsampling": 2.0}
    for budget in BUDGETS:
        a, b = load_config(budget, format="strayscanner"), load_config(budget, format="record3d")
        assert a.format_layer == "strayscanner" and b.format_layer == "record3d"
        assert dataclasses.replace(a, format_layer="record3d").to_dict() == b.to_dict()


def test_a_format_layers_base_must_be_a_format_layer(tmp_path, monkeypatch):
    (tmp_path / "formats").mkdir()
    (tmp_path / "cpu.yaml").write_text("tracking: {iterations: 2}\n")
    (tmp_path / "formats" / "tum.yaml").write_text("base: cpu\n")
    monkeypatch.setattr(C, "CONFIG_DIR", tmp_path)
    with pytest.raises(InputError, match="a format layer's base must be another format layer, not cpu"):
        load_config("splatam", format="tum")


def test_config_show_prints_a_resolved_config_that_loads_back(tmp_path, capsys):
    assert splatam_main(["config", "show", "cpu+splatam_s", "--format", "record3d"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# budget cpu+splatam_s + format layer record3d (max_depth 5.0")
    shown = yaml.safe_load(out)
    expected = load_config("cpu+splatam_s", format="record3d")
    assert shown == expected.to_dict()
    (tmp_path / "shown.yaml").write_text(out)
    again = load_config(str(tmp_path / "shown.yaml"))
    assert dataclasses.replace(again, name=expected.name).to_dict() == expected.to_dict()


@pytest.mark.parametrize("device, engine", [("cpu", "sequential"), ("cuda", "live"), ("cuda", "sequential")])
def test_config_show_without_a_name_shows_the_devices_default_preset(capsys, device, engine):
    assert splatam_main(["config", "show", "--device", device, "--engine", engine]) == 0
    out = capsys.readouterr().out
    assert yaml.safe_load(out)["name"] == C.default_preset(device, engine)
    assert yaml.safe_load(out) == load_config(C.default_preset(device, engine)).to_dict()


def test_config_show_refuses_an_unknown_format_or_preset(capsys):
    assert splatam_main(["config", "show", "cpu", "--format", "kinect"]) == 2
    assert "error: --format kinect: no format layer of that name" in capsys.readouterr().err
    assert splatam_main(["config", "show", "nope"]) == 2
    assert "error: nope: no such config file or preset" in capsys.readouterr().err


def test_the_default_preset_is_stated_once_and_every_command_uses_it(monkeypatch):
    from app.run_setup import load_run_config

    for (device, engine), preset in C.DEFAULT_PRESETS.items():
        assert load_run_config(None, "tum", device, engine=engine).name == preset
    monkeypatch.setitem(C.DEFAULT_PRESETS, ("cpu", "live"), "splatam_s")         # a later live preset
    assert load_run_config(None, "tum", "cpu", engine="live").name == "splatam_s"
    assert "live engine: splatam_s on a CPU" in C.describe_default_presets()
    for command in ("run", "batch", "info", "config"):        # each --help says it, from the table
        p = argparse.ArgumentParser()
        importlib.import_module(SUBCOMMANDS[command][0]).add_arguments(p)
        assert C.describe_default_presets() in " ".join(p.format_help().split()), command
    # no other module names a preset for a device
    root = C.CONFIG_DIR.parent
    for path in [*(root / "app").rglob("*.py"), *(root / "splat_core").rglob("*.py")]:
        if path != root / "splat_core" / "config.py":
            assert '"gpu"' not in path.read_text() and "splatam on a GPU" not in path.read_text(), path


def test_docs_settings_md_is_the_generated_page():
    from splat_core.config_schema import leaves
    from splat_core.settings_doc import render

    page = (C.CONFIG_DIR.parent / "docs" / "settings.md").read_text()
    assert page == render(), "docs/settings.md is stale: python -m splat_core.settings_doc > docs/settings.md"
    for key, _, _ in leaves(C.Config):
        assert f"| `{key}` |" in page
    assert "`cpu`: `2`" in page and "`strayscanner` (format layer): `5.0`" in page
    for doc in ("index.md", "presets.md"):
        assert "(settings.md)" in (C.CONFIG_DIR.parent / "docs" / doc).read_text(), doc
