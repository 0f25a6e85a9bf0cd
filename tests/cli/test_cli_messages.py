"""What the commands say to a new user: where a run went, a suggestion for a mistyped option, one
short line for photos without depth, and the viewer's access rules (issue 32); a mistyped command,
every export format, commands and pip as this shell can run them, what a Ctrl-C'd viewer wrote, and
the viewer's URL with its token without viser's banner (issue 45)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from app.cli import splatam_main, viewer_main
from app.console_commands import command, pip_install


def test_run_ends_with_where_it_went(tmp_path, capsys):
    out = tmp_path / "run"
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text("base: cpu\nresolution: [48, 36]\ntracking: {iterations: 2}\n"
                    "mapping: {iterations: 2, first_frame_iterations: 2}\n")
    assert splatam_main(["run", "--input", "synthetic", "--out", str(out), "--max-frames", "2",
                         "--config", str(tiny), "--engine", "sequential"]) == 0
    err = capsys.readouterr().err
    assert f"wrote {out}: view it with {command('splatam-viewer')} --open {out}" in err


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
    from splat_core.config import default_preset

    with pytest.raises(SystemExit):
        splatam_main(["batch", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    gpu, cpu = default_preset("cuda"), default_preset("cpu")
    assert f"{cpu} on a CPU" in help_text and f"{gpu} on an NVIDIA GPU" in help_text
    assert "splatam on a GPU" not in help_text


def test_a_mistyped_command_gets_one_line_and_a_suggestion(capsys):
    with pytest.raises(SystemExit) as exit_:
        splatam_main(["rn", "--input", "x"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.splitlines() == ["splatam: unknown command 'rn': did you mean run?"]
    with pytest.raises(SystemExit):
        splatam_main(["zzz"])
    assert "expected one of run, capture, info, convert, export" in capsys.readouterr().err


def test_an_unknown_export_format_lists_every_format(capsys):
    from app.commands.export import export_formats
    from app.exports import FORMATS
    from app.handoffs import HANDOFF_FORMATS

    assert set(export_formats()) == set(FORMATS) | set(HANDOFF_FORMATS)
    with pytest.raises(SystemExit):
        splatam_main(["export", "--help"])
    assert f"--format {'|'.join(export_formats())}" in capsys.readouterr().out
    assert splatam_main(["export", "runs/a", "--format", "colmp", "--out", "x"]) == 2
    err = capsys.readouterr().err
    assert f"expected one of {', '.join(export_formats())} (did you mean colmap?)" in err
    assert splatam_main(["export", "runs/a", "--out", "x.unknown"]) == 2            # no suffix names one
    assert f"pass --format {'|'.join(export_formats())}" in capsys.readouterr().err


@pytest.fixture
def venv(tmp_path, monkeypatch):
    """A virtual environment at tmp/.venv that runs this test (its scripts not on PATH), cwd tmp."""
    bin_dir = tmp_path / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    for name in ("python", "pip", "splatam", "splatam-viewer"):
        (bin_dir / name).write_text("#!/bin/sh\n")
        (bin_dir / name).chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(bin_dir / "python"))
    monkeypatch.setattr(sys, "prefix", str(tmp_path / ".venv"))
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.chdir(tmp_path)
    return bin_dir


def test_commands_name_the_venv_when_it_is_not_on_path(venv, monkeypatch, tmp_path):
    assert command("splatam-viewer") == ".venv/bin/splatam-viewer"
    assert pip_install("splatam-viewer[batch]") == ".venv/bin/pip install 'splatam-viewer[batch]'"
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")                           # not under the cwd: the whole path
    assert command("splatam") == f"{venv}/splatam"
    monkeypatch.setenv("PATH", f"{venv}:/usr/bin:/bin")                 # an activated venv: the bare names
    assert command("splatam") == "splatam" and pip_install("x") == "pip install x"
    monkeypatch.setattr(sys, "prefix", sys.base_prefix)                 # no venv: this interpreter's pip
    assert pip_install("splatam-viewer[batch]") == f"{venv}/python -m pip install 'splatam-viewer[batch]'"


def test_the_batch_extra_hint_installs_into_this_python(venv, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)               # Dask not installed
    assert splatam_main(["batch", "cap", "--out", "b"]) == 2
    assert capsys.readouterr().err.strip() == \
        "error: splatam batch needs Dask: .venv/bin/pip install 'splatam-viewer[batch]'"


@pytest.mark.slow
def test_ctrl_c_viewer_says_what_it_wrote_and_its_url_has_the_token(tmp_path):
    """On 127.0.0.2 (a token): our URL with the token and no viser banner (whose URL has none). Ctrl-C
    while SLAM runs: the run folder is written, and the viewer says where and how to open it."""
    out = tmp_path / "run"
    slow = tmp_path / "slow.yaml"        # frame 0 quick, every later one slow: Ctrl-C comes mid-run
    slow.write_text("base: cpu\nresolution: [48, 36]\ntracking: {iterations: 300}\n"
                    "mapping: {iterations: 300, first_frame_iterations: 2}\n")
    code = "import sys; from app.cli import viewer_main; sys.exit(viewer_main(sys.argv[1:]))"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[2]), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-c", code, "--host", "127.0.0.2", "--port", "0", "--out", str(out),
                             "--config", str(slow), "--engine", "sequential"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            # Ctrl-C as a terminal gives it, however the suite was started: a shell's
                            # background job (`make test &`) passes SIGINT on ignored, and Python keeps that
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while not (lines and lines[-1].startswith("URL ")):
            lines.append(proc.stdout.readline())
            assert lines[-1], "the viewer ended before printing its URL"
        keyframes, deadline = out / "checkpoint" / "keyframes.bin", time.monotonic() + 300
        while not (keyframes.is_file() and keyframes.stat().st_size > 0):   # frame 0 done (a keyframe)
            assert proc.poll() is None and time.monotonic() < deadline, "no first keyframe"
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        rest, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    stdout = "".join(lines) + rest
    assert proc.returncode == 0, err
    assert re.search(r"^URL http://127\.0\.0\.2:\d+/\?token=\S{20,}$", stdout, re.M), stdout
    assert "Websocket" not in stdout and "HTTP" not in stdout, stdout                # no viser banner
    assert "stopping SLAM after this frame" in err and (out / "map.ply").is_file()
    assert re.search(rf"^wrote {re.escape(str(out))}: view it later with \S*splatam-viewer --open "
                     rf"{re.escape(str(out))}$", stdout, re.M), stdout
