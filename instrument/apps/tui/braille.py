"""Line plots drawn with Unicode braille characters (2 x 4 dots per terminal cell), with tick-labelled axes.

Pure: data and a size in cells in, lines of styled text out. One style per cell (the last trace drawn in a
cell colours it). Non-finite values break a line; values outside the axes are clipped away.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from rich.text import Text

BRAILLE_BLANK = 0x2800
#: bit of the dot at (row 0..3, column 0..1) inside a braille cell
DOT_BITS: tuple[tuple[int, int], ...] = ((0x01, 0x08), (0x02, 0x10), (0x04, 0x20), (0x40, 0x80))


class PlotError(ValueError):
    """An axis or trace that cannot be drawn (empty or reversed range, non-positive log bound, shape mismatch)."""


@dataclass(frozen=True)
class Axis:
    """A plot axis from ``lo`` to ``hi`` (data units), logarithmic when ``log`` (then 0 < lo)."""

    lo: float
    hi: float
    log: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
            raise PlotError(f"axis range must be finite with lo < hi, got [{self.lo!r}, {self.hi!r}]")
        if self.log and self.lo <= 0.0:
            raise PlotError(f"log axis needs lo > 0, got {self.lo!r}")

    def fraction(self, values: np.ndarray) -> np.ndarray:
        """Position of ``values`` along the axis, 0 at ``lo`` and 1 at ``hi`` (NaN where not drawable)."""
        v = np.asarray(values, dtype=float)
        if self.log:
            with np.errstate(divide="ignore", invalid="ignore"):
                out = (np.log10(np.where(v > 0, v, np.nan)) - math.log10(self.lo)) / math.log10(self.hi / self.lo)
        else:
            out = (v - self.lo) / (self.hi - self.lo)
        return np.where(np.isfinite(out), out, np.nan)

    def ticks(self, max_ticks: int) -> list[float]:
        """Round tick values inside the axis: decades (with 2 and 5 when few) on a log axis, 1-2-5 steps else."""
        max_ticks = max(2, max_ticks)
        if self.log:
            first, last = math.ceil(math.log10(self.lo) - 1e-9), math.floor(math.log10(self.hi) + 1e-9)
            decades = [10.0 ** e for e in range(first, last + 1)]
            stride = max(1, math.ceil(len(decades) / max_ticks))
            ticks = decades[::stride]
            if len(decades) < 2:
                extra = [m * 10.0 ** e for e in range(first - 1, last + 1) for m in (2.0, 5.0)]
                ticks = sorted({*ticks, *(t for t in extra if self.lo <= t <= self.hi)})
                if len(ticks) > max_ticks:
                    ticks = ticks[:: math.ceil(len(ticks) / max_ticks)]
            return ticks
        span = self.hi - self.lo
        raw = span / max_ticks
        magnitude = 10.0 ** math.floor(math.log10(raw))
        step = next(m * magnitude for m in (1.0, 2.0, 5.0, 10.0) if m * magnitude >= raw)
        start = math.ceil(self.lo / step - 1e-9)
        stop = math.floor(self.hi / step + 1e-9)
        return [k * step for k in range(start, stop + 1)]


@dataclass(frozen=True)
class Trace:
    """Points (x, y) joined by lines (``lines``) or as dots, in a rich ``style`` (a colour name)."""

    x: np.ndarray
    y: np.ndarray
    style: str = "white"
    lines: bool = True

    def __post_init__(self) -> None:
        x, y = np.asarray(self.x, dtype=float).ravel(), np.asarray(self.y, dtype=float).ravel()
        if x.shape != y.shape:
            raise PlotError(f"trace x and y differ in length: {x.size} and {y.size}")
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)


@dataclass(frozen=True)
class HLine:
    """A dashed horizontal line at ``y`` (data units)."""

    y: float
    style: str = "red"


class BrailleCanvas:
    """A grid of ``cols`` x ``rows`` cells = (2 cols) x (4 rows) dots; dot (0, 0) is at the top left."""

    def __init__(self, cols: int, rows: int) -> None:
        if cols < 1 or rows < 1:
            raise PlotError(f"canvas needs at least one cell, got {cols} x {rows}")
        self.cols, self.rows = cols, rows
        self.bits = np.zeros((rows, cols), dtype=np.uint8)
        self.styles: list[list[str | None]] = [[None] * cols for _ in range(rows)]

    @property
    def width(self) -> int:
        """Dots across."""
        return 2 * self.cols

    @property
    def height(self) -> int:
        """Dots down."""
        return 4 * self.rows

    def dot(self, px: int, py: int, style: str) -> None:
        """Set the dot at column ``px``, row ``py`` (ignored outside the canvas)."""
        if 0 <= px < self.width and 0 <= py < self.height:
            r, c = py // 4, px // 2
            self.bits[r, c] |= DOT_BITS[py % 4][px % 2]
            self.styles[r][c] = style

    def line(self, x0: int, y0: int, x1: int, y1: int, style: str) -> None:
        """Dots from (x0, y0) to (x1, y1) inclusive (Bresenham)."""
        dx, dy = abs(x1 - x0), -abs(y1 - y0)
        sx, sy = (1 if x1 >= x0 else -1), (1 if y1 >= y0 else -1)
        err = dx + dy
        for _ in range(dx - dy + 1):
            self.dot(x0, y0, style)
            if x0 == x1 and y0 == y1:
                break
            e2 = 2 * err
            if e2 >= dy:
                err += dy
                x0 += sx
            if e2 <= dx:
                err += dx
                y0 += sy

    def lines(self) -> list[Text]:
        """The canvas as one styled text line per row of cells (one span per run of equally styled cells)."""
        out: list[Text] = []
        for r in range(self.rows):
            chars = "".join(chr(BRAILLE_BLANK + int(b)) for b in self.bits[r])
            text = Text(chars)
            styles = self.styles[r]
            start = 0
            for c in range(1, self.cols + 1):
                if c == self.cols or styles[c] != styles[start]:
                    style = styles[start]
                    if style:
                        text.stylize(style, start, c)
                    start = c
            out.append(text)
        return out


def auto_axis(values: Sequence[np.ndarray] | np.ndarray, log: bool = False, include: Sequence[float] = ()) -> Axis:
    """An axis covering the finite values (positive ones when ``log``) and ``include``; log axes snap to
    decades, linear ones get 5 % margins. With nothing to cover: [1, 10] (log) or [-1, 1]."""
    arrays = [np.asarray(v, dtype=float).ravel() for v in (values if isinstance(values, (list, tuple)) else [values])]
    data = np.concatenate([*arrays, np.asarray(include, dtype=float)]) if arrays or include else np.empty(0)
    data = data[np.isfinite(data)]
    if log:
        data = data[data > 0]
        if data.size == 0:
            return Axis(1.0, 10.0, log=True)
        lo = 10.0 ** math.floor(math.log10(float(data.min())) + 1e-12)
        hi = 10.0 ** math.ceil(math.log10(float(data.max())) - 1e-12)
        if hi <= lo:
            hi = lo * 10.0
        return Axis(lo, hi, log=True)
    if data.size == 0:
        return Axis(-1.0, 1.0)
    lo, hi = float(data.min()), float(data.max())
    if hi - lo <= 1e-12 * max(1.0, abs(lo), abs(hi)):
        pad = max(abs(lo) * 0.1, 1e-9)
        return Axis(lo - pad, hi + pad)
    pad = 0.05 * (hi - lo)
    return Axis(lo - pad, hi + pad)


def format_tick(value: float) -> str:
    """Short label: 3 significant digits, SI-style k/M for large magnitudes, exponent for tiny ones."""
    if value == 0:
        return "0"
    a = abs(value)
    if a >= 1e6:
        return f"{value / 1e6:.3g}M"
    if a >= 1e3:
        return f"{value / 1e3:.3g}k"
    if a >= 1e-3:
        return f"{value:.3g}"
    return f"{value:.0e}"


def render_plot(traces: Sequence[Trace], width: int, height: int, x_axis: Axis, y_axis: Axis,
                hlines: Sequence[HLine] = (), axis_style: str = "bright_black") -> list[Text]:
    """The plot in ``width`` x ``height`` cells: y tick labels on the left, x tick labels on the last line.

    Returns exactly ``height`` lines, each at most ``width`` cells; a notice instead when the size is too small.
    """
    if width < 1 or height < 1:
        return []
    y_ticks = y_axis.ticks(max(2, (height - 1) // 2))
    labels = [format_tick(t) for t in y_ticks]
    margin = max((len(s) for s in labels), default=1)
    cols, rows = width - margin - 1, height - 1
    if cols < 4 or rows < 2:
        return [Text("(too small)"[:width])] + [Text("") for _ in range(height - 1)]
    canvas = BrailleCanvas(cols, rows)
    for h in hlines:
        fy = float(y_axis.fraction(np.array([h.y]))[0])
        if math.isfinite(fy) and 0.0 <= fy <= 1.0:
            py = round((1.0 - fy) * (canvas.height - 1))
            for px in range(canvas.width):
                if px % 4 < 2:
                    canvas.dot(px, py, h.style)
    for trace in traces:
        _draw_trace(canvas, trace, x_axis, y_axis)
    body = canvas.lines()
    tick_rows: dict[int, str] = {}
    for value, label in zip(y_ticks, labels, strict=True):
        fy = float(y_axis.fraction(np.array([value]))[0])
        if math.isfinite(fy):
            tick_rows.setdefault(round((1.0 - fy) * (canvas.height - 1)) // 4, label)
    out: list[Text] = []
    for r, line in enumerate(body):
        tick = tick_rows.get(r)
        text = Text(tick.rjust(margin) if tick else " " * margin, style=axis_style)
        text.append("┤" if tick else "│", style=axis_style)
        text.append_text(line)
        out.append(text)
    out.append(_x_labels(x_axis, cols, margin, axis_style))
    return out


def _draw_trace(canvas: BrailleCanvas, trace: Trace, x_axis: Axis, y_axis: Axis) -> None:
    """Draw ``trace`` on ``canvas`` (thinned to twice the dots across when it has more points)."""
    x, y = trace.x, trace.y
    limit = 2 * canvas.width
    if x.size > limit:  # more points than the canvas can show: every step-th, and the last
        step = -(-x.size // limit)
        keep = np.r_[np.arange(0, x.size - 1, step), x.size - 1]
        x, y = x[keep], y[keep]
    fx, fy = x_axis.fraction(x), y_axis.fraction(y)
    px = np.round(fx * (canvas.width - 1))
    py = np.round((1.0 - fy) * (canvas.height - 1))
    inside = np.isfinite(px) & np.isfinite(py) & (fx >= -1e-9) & (fx <= 1 + 1e-9) & (fy >= -1e-9) & (fy <= 1 + 1e-9)
    prev: tuple[int, int] | None = None
    for i in range(px.size):
        if not inside[i]:
            prev = None
            continue
        point = (int(px[i]), int(py[i]))
        if trace.lines and prev is not None:
            canvas.line(prev[0], prev[1], point[0], point[1], trace.style)
        else:
            canvas.dot(point[0], point[1], trace.style)
        prev = point


def _x_labels(x_axis: Axis, cols: int, margin: int, style: str) -> Text:
    """The bottom line: corner, then x tick labels centred on their columns without overlapping."""
    line = [" "] * (margin + 1 + cols)
    line[margin] = "└"
    taken = margin  # last column used by a label
    for value in x_axis.ticks(max(2, cols // 8)):
        f = float(x_axis.fraction(np.array([value]))[0])
        if not math.isfinite(f):
            continue
        label = format_tick(value)
        centre = margin + 1 + round(f * (cols - 1))
        start = min(max(centre - len(label) // 2, margin + 1), len(line) - len(label))
        if start <= taken:
            continue
        line[start:start + len(label)] = list(label)
        taken = start + len(label)
    return Text("".join(line), style=style)
