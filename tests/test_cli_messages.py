"""What the commands say to a new user: where a run went, a suggestion for a mistyped option, one
short line for photos without depth, and the viewer's access rules (issue 32)."""

from __future__ import annotations

import pytest

from app.cli import splatam_main, viewer_main


def test_run_ends_with_where_it_went(tmp_path, capsys):
    out = tmp_path / "run"
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text("base: cpu\nresolution: [48, 36]\ntracking: {iterations: 2}\n"
                    "mapping: {iterations: 2, first_frame_iterations: 2}\n")
    assert splatam_main(["run", "--input", "synthetic", "--out", str(out), "--max-frames", "2",
                         "--config", str(tiny), "--engine", "sequential"]) == 0
    err = capsys.readouterr().err
    assert f"wrote {out}: view it with splatam-viewer --open {out}" in err


@pytest.mark.parametrize("argv, usage, hint", [
    (["run", "--input", "x", "--out", "y", "--max-frmes", "3"], "usage: splatam run", "did you mean --max-frames?"),
    (["export", "runs/a", "--formt", "spz"], "usage: splatam export", "did you mean --format?"),
])
def test_option_typos_get_the_subcommands_usage_and_a_suggestion(argv, usage, hint, capsys):
    with pytest.raises(SystemExit) as exit_:
        splatam_main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and usage in err and hint in err


def test_viewer_option_typo(capsys):
    with pytest.raises(SystemExit):
        viewer_main(["--shrae", "view"])
    err = capsys.readouterr().err
    assert "usage: splatam-viewer" in err and "did you mean --share?" in err


def test_photos_without_depth_get_one_short_line(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        (photos / f"IMG_{i:04d}.JPG").write_bytes(b"\xff\xd8")
    assert splatam_main(["info", "--input", str(photos)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {photos}: 3 photo(s) but no depth found: this needs RGB-D (a depth image per frame, " \
                  "e.g. from a LiDAR phone app or a depth camera)"


def test_access_rules():
    from app.viewer.access import Access

    for host in ("127.0.0.1", "::1", "localhost"):
        assert not Access.for_host(host).required                      # loopback stays as it was
    for host in ("0.0.0.0", "127.0.0.2", "192.168.1.5", "::"):
        access = Access.for_host(host)
        assert access.required and len(access.token_for("control")) >= 20
        assert "?token=" in access.url(host, 8080)
    view = Access.for_host("127.0.0.1", share="view")                 # view-only needs tokens anywhere
    assert view.required and view.token_for("view") != view.token_for("control")
    assert Access.for_host("0.0.0.0", token="my-own-token").token_for("control") == "my-own-token"


def test_batch_help_names_the_default_preset_run_uses(capsys):
    import torch

    from app.run_setup import default_config_name

    with pytest.raises(SystemExit):
        splatam_main(["batch", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    gpu, cpu = default_config_name(torch.device("cuda")), default_config_name(torch.device("cpu"))
    assert f"{cpu} on a CPU, {gpu} on a GPU" in help_text and "splatam on a GPU" not in help_text
