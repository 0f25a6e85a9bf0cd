"""The Plots panel: tracking loss, ATE, the live render's PSNR and seconds per frame against the
frame number, each with its latest value written above it.

uPlot (viser 1.1.1's add_uplot) takes only JSON options, no JavaScript callbacks, and left to
itself it drew one y tick or none on these short plots, and labels with at most three decimals
("0" for a tracking loss of 0.0004). So the y ticks are chosen here: a few round values covering
the data, sent as the y axis' `splits` with their labels as `values`, and the y scale fixed to
the ticks' range. They change only when the data leaves that range, so the chart (rebuilt by the
page whenever its axes change) is not rebuilt on every update. uPlot's legend reads `--` until
the pointer is over the plot; it is off, and the latest value is page text above each plot.
The x axis is the frame number (uPlot's x scale with time off; by default it reads the x values
as UNIX times).
"""

from __future__ import annotations

import math

import numpy as np

PLOTS = (  # history key, title, colour, latest value's format
    ("tracking_loss", "Tracking loss", "#e87026", "{:.3g}"),
    ("ate_cm", "ATE up to each frame", "#28aa5a", "{:.2f} cm"),
    ("psnr", "PSNR of the live render", "#3c6ee6", "{:.1f} dB"),
    ("seconds", "Seconds per frame", "#888888", "{:.2f} s"),
)
STEPS = (1.0, 2.0, 2.5, 5.0, 10.0)    # tick spacings (times a power of ten)
CHAR_PX, AXIS_PAD_PX = 7, 16          # a digit of uPlot's 12 px axis font; tick and gap beside it
FRAME_STEPS = tuple(m * 10 ** k for k in range(7) for m in (1, 2, 5))   # whole frames only
X_AXIS = {"label": "frame", "size": 30, "labelSize": 20, "incrs": FRAME_STEPS}   # compact: the plot keeps its height


def nice_ticks(lo: float, hi: float, target: int = 4) -> np.ndarray:
    """About `target` (3 to 6) round, evenly spaced values whose range covers [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"ticks of a non-finite range [{lo}, {hi}]")
    if hi <= lo:
        pad = abs(lo) * 0.1 or 1.0
        lo, hi = lo - pad, hi + pad
    raw = (hi - lo) / max(target - 1, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(s * power for s in STEPS if s * power >= raw * (1 - 1e-9))
    first, last = math.floor(lo / step + 1e-9), math.ceil(hi / step - 1e-9)
    return np.arange(first, last + 1) * step


def tick_labels(ticks: np.ndarray) -> list[str]:
    """Labels that tell the ticks apart with as few digits as they need: exponents for a spacing
    below 1e-3 or values from 1e5 ("5.0e-4", "1.5e-3", "2e5"), otherwise fixed-point ("0.025", "12.5", "1500")."""
    step = float(ticks[1] - ticks[0]) if len(ticks) > 1 else 1.0
    biggest = float(np.max(np.abs(ticks)))
    if step < 1e-3 or biggest >= 1e5:
        digits = max(0, math.floor(math.log10(biggest)) - math.floor(math.log10(step)) + step_digits(step))
        return [_short_exponent(f"{t:.{digits}e}") if t else "0" for t in ticks]
    decimals = max(0, -math.floor(math.log10(step)) + step_digits(step))
    return [f"{t:.{decimals}f}" for t in ticks]


def step_digits(step: float) -> int:
    """Digits a spacing needs beyond its leading one: 1 for 2.5 (0.25, 25), else 0."""
    mantissa = step / 10.0 ** math.floor(math.log10(step))
    return 1 if abs(mantissa - 2.5) < 1e-6 else 0


def _short_exponent(text: str) -> str:
    mantissa, exponent = text.split("e")
    return f"{mantissa}e{int(exponent)}"


def y_axis(values: np.ndarray) -> tuple[dict, dict]:
    """(the y axis, the y scale) for these values: round ticks, their labels, a range that holds them."""
    ticks = nice_ticks(float(np.min(values)), float(np.max(values)))
    labels = tick_labels(ticks)
    axis = {"splits": tuple(float(t) for t in ticks), "values": tuple(labels),
            "size": AXIS_PAD_PX + CHAR_PX * max(len(label) for label in labels)}
    return axis, {"auto": False, "range": (float(ticks[0]), float(ticks[-1]))}


def latest_text(title: str, fmt: str, x: np.ndarray, y: np.ndarray, none: str = "no values yet") -> str:
    if len(y) == 0:
        return f"**{title}**: {none}"
    return f"**{title}**: {fmt.format(y[-1])} (frame {int(x[-1])})"


class PlotsPanel:
    """The folder of plots on the shared GUI (every page), and what each one shows."""

    def __init__(self, gui, order: float = 3, expanded: bool = True, height: int = 150):
        self.handles: dict[str, object] = {}
        self.latest: dict[str, object] = {}
        self._axes: dict[str, tuple] = {}
        with gui.add_folder("Plots", order=order, expand_by_default=expanded):
            for key, title, colour, _fmt in PLOTS:
                self.latest[key] = gui.add_markdown(f"**{title}**: no values yet")
                self.handles[key] = gui.add_uplot(
                    data=(np.zeros(1), np.zeros(1)),
                    series=({"label": "frame"}, {"label": title, "stroke": colour, "width": 2}),
                    scales={"x": {"time": False}}, axes=(X_AXIS, {}),
                    legend={"show": False}, height=height, padding=(12, 24, 0, 0))

    def update(self, history: dict, none: dict | None = None) -> None:
        """Show a snapshot's history (HISTORY_KEYS -> one value per frame, NaN where none); `none`:
        what to say instead of a value, by key (the ATE without reference poses)."""
        if not history or len(history.get("frame", ())) == 0:
            return
        x = np.asarray(history["frame"], np.float64)
        for key, title, _colour, fmt in PLOTS:
            y = np.asarray(history.get(key, np.full_like(x, np.nan)), np.float64)
            ok = np.isfinite(y)
            text = latest_text(title, fmt, x[ok], y[ok], (none or {}).get(key, "no values yet"))
            if self.latest[key].content != text:
                self.latest[key].content = text
            if ok.any():
                self._show(key, x[ok], y[ok])

    def _show(self, key: str, x: np.ndarray, y: np.ndarray) -> None:
        handle = self.handles[key]
        axis, scale = y_axis(y)
        if self._axes.get(key) != (axis, scale):
            self._axes[key] = (axis, scale)
            handle.axes = (X_AXIS, axis)
            handle.scales = {"x": {"time": False}, "y": scale}
        handle.data = (x, y)
