"""The issue-44 benchmark tools on the real 7-Scenes data (skipped without ../shared/data): a "run"
that is the KinectFusion reference itself must score zero against it in every tool."""

from __future__ import annotations

import json
import shutil

from conftest import shared_sequence


def _reference_as_run(tmp_path, folder):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(folder / "groundtruth.txt", run / "trajectory.txt")
    return run


def test_reference_blend_starts_at_the_run_and_ends_at_the_reference(tmp_path, capsys):
    from reference_blend import main
    folder = shared_sequence("7scenes_redkitchen_300")
    run = _reference_as_run(tmp_path, folder)
    assert main(["--run", str(run), "--sequence", folder.name, "--data", str(folder.parent), "--steps", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["cuts"] == [122]
    assert [r["kinectfusion_split_cm"] for r in out["rows"]] == [0.0, 0.0, 0.0]
    assert out["rows"][0]["sfm_se3_cm"] == out["rows"][-1]["sfm_se3_cm"] > 1.0


def test_pair_evidence_gives_the_run_and_the_reference_it_copies_the_same_figures(tmp_path, capsys):
    from pair_evidence import main
    folder = shared_sequence("7scenes_redkitchen_300")
    run = _reference_as_run(tmp_path, folder)
    assert main(["--run", str(run), "--sequence", folder.name, "--data", str(folder.parent), "10-12"]) == 0
    row = json.loads(capsys.readouterr().out)["pairs"][0]
    assert row["pair"] == "10-12"
    assert row["dz_median_mm_run"] == row["dz_median_mm_kinectfusion"] < 20
    assert 0 <= row["within_1cm_sfm"] <= 1
