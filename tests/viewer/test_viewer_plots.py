"""The plots' y axes (app/viewer/plots.py): round ticks covering the data, labels that tell them apart
at any magnitude, and the latest value written above each plot. The page: test_viewer_visitors_browser.py."""

from __future__ import annotations

import numpy as np
import pytest

from app.viewer.plots import PlotsPanel, nice_ticks, tick_labels, y_axis


@pytest.mark.parametrize("lo, hi", [(0.008, 0.032), (0.05, 0.65), (22.8, 25.2), (0.24, 0.36), (0.0004, 0.0013),
                                    (1.2e-6, 1.9e-6), (1200.0, 4800.0), (0.0, 3.0e5), (-0.3, 0.2), (5.0, 5.0),
                                    (0.0, 0.0)])
def test_ticks_cover_the_data_and_their_labels_tell_them_apart(lo, hi):
    ticks = nice_ticks(lo, hi)
    labels = tick_labels(ticks)
    assert 3 <= len(ticks) <= 6, ticks
    assert ticks[0] <= lo and ticks[-1] >= hi
    step = ticks[1] - ticks[0]
    assert np.allclose(np.diff(ticks), step)
    assert len(set(labels)) == len(labels), labels                 # never "0", "0", "0"
    assert np.allclose([float(label) for label in labels], ticks, atol=step * 1e-6), labels
    assert max(len(label) for label in labels) <= 7, labels


@pytest.mark.parametrize("lo, hi, labels", [
    (0.008, 0.032, ["0.00", "0.01", "0.02", "0.03", "0.04"]),
    (0.0004, 0.0013, ["0", "5.0e-4", "1.0e-3", "1.5e-3"]),         # not "0", "0.001" (uPlot's own labels)
    (1.2e-6, 1.9e-6, ["1.00e-6", "1.25e-6", "1.50e-6", "1.75e-6", "2.00e-6"]),
    (22.8, 25.2, ["22", "23", "24", "25", "26"]),
    (0.0, 3.0e5, ["0", "1e5", "2e5", "3e5"]),
])
def test_labels_at_every_magnitude(lo, hi, labels):
    assert tick_labels(nice_ticks(lo, hi)) == labels


def test_the_axis_is_as_wide_as_its_longest_label():
    narrow, _ = y_axis(np.array([1.0, 3.0]))
    wide, scale = y_axis(np.array([0.0004, 0.0013]))
    assert wide["size"] > narrow["size"]
    assert scale["range"] == (wide["splits"][0], wide["splits"][-1]) and scale["auto"] is False


def test_latest_values_above_the_plots_and_axes_sent_only_when_the_range_changes(server):
    panel = PlotsPanel(server.gui)
    x = np.arange(4.0)
    history = {"frame": x, "tracking_loss": np.array([0.02, 0.021, 0.0185, 0.0192]),
               "ate_cm": np.full(4, np.nan), "psnr": np.array([np.nan, 24.0, np.nan, 25.5]),
               "seconds": np.array([0.31, 0.3, 0.33, 0.32])}
    panel.update(history, {"ate_cm": "n/a (no reference poses)"})
    assert panel.latest["tracking_loss"].content == "**Tracking loss**: 0.0192 (frame 3)"
    assert panel.latest["psnr"].content == "**PSNR of the live render**: 25.5 dB (frame 3)"
    assert panel.latest["seconds"].content == "**Seconds per frame**: 0.32 s (frame 3)"
    assert panel.latest["ate_cm"].content == "**ATE up to each frame**: n/a (no reference poses)"
    loss = panel.handles["tracking_loss"]
    axes = loss.axes
    assert axes[1]["values"] == tuple(tick_labels(nice_ticks(0.0185, 0.021)))
    history = dict(history, frame=np.arange(5.0), tracking_loss=np.append(history["tracking_loss"], 0.0195),
                   ate_cm=np.full(5, np.nan), psnr=np.full(5, np.nan), seconds=np.full(5, 0.3))
    panel.update(history)
    assert loss.axes is axes and len(loss.data[0]) == 5                # same range: the chart is not rebuilt
    panel.update(dict(history, tracking_loss=np.append(history["tracking_loss"][:4], 0.05)))
    assert loss.axes is not axes and loss.axes[1]["splits"][-1] >= 0.05
