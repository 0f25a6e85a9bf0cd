"""What the viewer's panels say (issue 45): no source file names, hints that name every choice, notes that
follow the run, and no run-control instructions on pages without the controls."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from app.snapshot import MapSnapshot
from app.viewer.export_panel import LABELS, format_hint
from app.viewer.panels import status_markdown
from app.viewer.refine_panel import RefinePanel

SOURCE_FILE = re.compile(r"\w\.py\b")


def snapshot(state: str, out_dir: Path | None = None) -> MapSnapshot:
    return MapSnapshot(version=1, state=state, frame_index=3, total_frames=10, map_version=1,
                       gaussians={"means": np.zeros((5, 3))}, out_dir=out_dir)


def test_export_choices_name_no_source_file_and_the_hint_names_each_kind():
    for text in list(LABELS.values()) + [format_hint(tuple(LABELS))]:
        assert not SOURCE_FILE.search(text), text
    full = format_hint(tuple(LABELS))
    assert "map" in full and "trajectory" in full and "mesh" in full
    assert "mesh" not in format_hint(tuple(f for f in LABELS if f != "mesh"))


def test_refine_note_follows_the_run(server, tmp_path):
    panel = RefinePanel(server, feed=None)
    panel.sync(snapshot("running", tmp_path))
    assert "once SLAM has finished" in panel.info.content
    panel.sync(snapshot("finished", tmp_path))          # the run folder is written: say what Refine writes
    assert "needs a run folder" not in panel.info.content
    assert str(tmp_path / "map_refined.ply") in panel.info.content and not panel.button.disabled
    panel.sync(snapshot("browse", None))                # a .ply without its run folder
    assert "needs a run folder" in panel.info.content and panel.button.disabled


def test_the_shared_status_gives_no_instructions_for_the_run_controls():
    """The status line is on every page, view-only ones too: the words for pause say no more than that."""
    text = status_markdown(snapshot("paused"))
    assert "paused" in text and "Resume" not in text and "Step" not in text


def test_the_status_counts_the_frames_a_live_source_dropped():
    """A live source (the stream, --realtime): frames received, processed and dropped; none otherwise."""
    import dataclasses

    text = status_markdown(dataclasses.replace(snapshot("running"), received=(30, 26)))
    assert "Frames received: 30 · processed 4 · dropped **26**" in text
    assert "received" not in status_markdown(snapshot("running"))


def test_the_status_says_when_the_map_is_drawn_as_points():
    """`--draw-while-running auto` draws points for a page without a GPU: the status says why."""
    assert "drawn as points" in status_markdown(snapshot("running"), "points")
    assert "points" not in status_markdown(snapshot("running"), "splats")
    assert "points" not in status_markdown(snapshot("paused"), "points")    # splats again once paused
