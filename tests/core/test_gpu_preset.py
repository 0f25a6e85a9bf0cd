"""The `gpu` preset, `--device auto`'s choice, and the nested tracking.align section (config.py)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from app.run_setup import load_run_config
from splat_core.config import MOVED_KEYS, AlignConfig, config_from_dict, default_preset, load_config
from splat_core.errors import InputError


def test_device_auto_picks_the_gpu_preset_on_cuda_and_cpu_elsewhere():
    for engine in ("sequential", "live"):
        assert default_preset(torch.device("cuda"), engine) == default_preset("cuda", engine) == "gpu"
        cpu = {"sequential": "cpu", "live": "live"}[engine]       # the live engine's own preset on a CPU
        assert default_preset(torch.device("cpu"), engine) == default_preset("cpu", engine) == cpu
        assert load_run_config(None, "synthetic", torch.device("cuda"), engine=engine).name == "gpu"
        assert load_run_config(None, "synthetic", torch.device("cpu"), engine=engine).name == cpu
    with pytest.raises(InputError, match="no default preset for device mps"):
        default_preset("mps")


def test_gpu_preset_is_live_sized_and_the_paper_presets_stay_the_papers():
    gpu = load_config("gpu")
    assert gpu.resolution == [640, 480] and gpu.tracking.pixels == "all"
    assert gpu.tracking.align.iterations > 0 and gpu.tracking.align.backend == "auto"
    assert 0 < gpu.tracking.iterations <= 10 and 0 < gpu.mapping.iterations <= 20
    assert gpu.mapping.tile_fraction == 1.0          # gsplat draws every tile anyway
    splatam = load_config("splatam")
    assert (splatam.tracking.iterations, splatam.mapping.iterations, splatam.mapping.window_size) == (40, 60, 24)
    assert splatam.tracking.align == AlignConfig() and splatam.tracking.align.iterations == 0
    for name in ("splatam_s", "splatam_tum", "splatam_scannet", "splatam_scannetpp", "splatam_iphone"):
        assert load_config(name).tracking.align == AlignConfig(), name


def test_cpu_preset_keeps_its_alignment_settings_in_the_section():
    cpu = load_config("cpu")
    assert cpu.tracking.align == AlignConfig(iterations=10, depth_noise=True, stride=4, tolerance=1e-4)
    assert load_config("cpu_dense").tracking.align == dataclasses.replace(cpu.tracking.align, stride=1)


@pytest.mark.parametrize("old,new", [("align_iterations", "iterations"), ("align_stride", "stride"),
                                     ("align_color_weight", "color_weight"), ("align_min_points", "min_points")])
def test_old_flat_align_keys_are_errors_naming_the_new_key(tmp_path, old, new):
    with pytest.raises(InputError, match=rf"tracking\.{old} is now tracking\.align\.{new}"):
        load_config("cpu", overrides={"tracking": {old: 1}})
    path = tmp_path / "mine.yaml"
    path.write_text(f"base: cpu\ntracking:\n  {old}: 1\n")
    with pytest.raises(InputError, match=rf"mine\.yaml.*tracking\.align\.{new}"):
        load_config(str(path))


def test_align_section_validates_and_rejects_unknown_keys():
    with pytest.raises(InputError, match="backend"):
        load_config("cpu", overrides={"tracking": {"align": {"backend": "cuda"}}})
    with pytest.raises(InputError, match="unknown config key 'strides'"):
        load_config("cpu", overrides={"tracking": {"align": {"strides": 2}}})
    with pytest.raises(InputError, match="align.levels"):
        load_config("cpu", overrides={"tracking": {"align": {"levels": 0}}})
    assert load_config("cpu", overrides={"tracking": {"align": {"backend": "torch"}}}).tracking.align.backend == "torch"


def test_a_run_folder_written_before_the_section_is_read_with_its_keys_moved():
    old = load_config("cpu").to_dict()
    align = old["tracking"].pop("align")
    flat = {old_key for _, old_key in MOVED_KEYS}      # the keys that were flat (later ones never were)
    old["tracking"].update({f"align_{k}": v for k, v in align.items() if f"align_{k}" in flat})
    config = config_from_dict(old)
    # keys the section gained later (the tolerance) were not in such a folder: their defaults, as it ran
    assert config.tracking.align == dataclasses.replace(load_config("cpu").tracking.align,
                                                        tolerance=AlignConfig().tolerance)
    assert config_from_dict(load_config("gpu").to_dict()).to_dict() == load_config("gpu").to_dict()
