"""The sweep view: overall progress above a table with one row per (frequency, harmonic, channel)."""

from __future__ import annotations

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import DataTable, Static

from bodebench.apps.tui.model import Row, SweepModel, format_duration
from bodebench.apps.tui.widgets import STATE_STYLES, number_cell, percent_cell

#: sweep table columns: (key, label, width in cells); with a cell of padding each side 76 cells, within the
#: sweep panel's 78 at 160 x 48 (no horizontal scroll bar)
COLUMNS = (("f", "f Hz", 7), ("k", "k", 2), ("ch", "channel", 8), ("state", "state", 11), ("gain", "gain dB", 7),
           ("phase", "phase °", 7), ("periods", "periods", 7), ("thd", "THD %", 5), ("coh", "coh", 4))

#: refreshes between redraws of the table for period counts alone (redrawing it is one of the UI's dearest
#: operations); a row whose state changed is redrawn at the next refresh
ROW_PERIODS_EVERY = 3


class SweepTable(DataTable):
    """One row per (frequency, harmonic, channel); rows and columns are addressed by key."""

    DEFAULT_CSS = """
    SweepTable { height: 1fr; }
    """

    def on_mount(self) -> None:
        self.cursor_type = "row"
        self.zebra_stripes = True
        for key, label, width in COLUMNS:
            self.add_column(label, key=key, width=width)

    def fill(self, rows: dict[str, Row]) -> None:
        """Replace every row."""
        self.clear()
        for key, row in rows.items():
            self.add_row(*self._cells(row), key=key)

    def update_row(self, key: str, row: Row) -> None:
        for (column, _, _), cell in zip(COLUMNS, self._cells(row), strict=True):
            self.update_cell(key, column, cell)

    @staticmethod
    def _cells(row: Row) -> list[object]:
        style = STATE_STYLES.get(row.state, "")
        return [Text(f"{row.frequency_hz:g}", justify="right"), str(row.harmonic), row.channel,
                Text(row.state, style=style),
                Text(number_cell(row.gain_db, "+.2f"), justify="right"),
                Text(number_cell(row.phase_deg, ".1f"), justify="right"),
                Text(str(row.periods) if row.periods else "", justify="right"),
                Text(percent_cell(row.thd), justify="right"),
                Text(number_cell(row.coherence, ".3f"), justify="right")]

    def selected_key(self) -> str | None:
        """Key of the row under the cursor (None when the table is empty)."""
        if self.row_count == 0:
            return None
        return self.coordinate_to_cell_key(self.cursor_coordinate).row_key.value


class SweepPanel(Vertical):
    """Overall progress (frequencies done, elapsed, to finish, rows per state) above the table of points, both
    drawn from a :class:`~bodebench.apps.tui.model.SweepModel`."""

    DEFAULT_CSS = """
    SweepPanel { height: 1fr; }
    SweepPanel #sweep-progress { height: 1; }
    """

    def __init__(self, *, id: str | None = None, classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self.progress = Static("", id="sweep-progress")
        self.table = SweepTable(id="sweep-table")
        self._refreshes = 0

    def compose(self) -> ComposeResult:
        yield self.progress
        yield self.table

    def fill(self, model: SweepModel) -> None:
        """Show every row of ``model`` (a new sweep, or rows added)."""
        self.table.fill(model.rows)
        model.take_changed()

    def show_rows(self, model: SweepModel, periods_too: bool = True) -> None:
        """Redraw the rows of ``model`` that changed: at once when a state changed, else (period counts only)
        when ``periods_too``."""
        if not (model.state_changed or periods_too):
            return
        for key in model.take_changed():
            self.table.update_row(key, model.rows[key])

    def tick(self, model: SweepModel) -> None:
        """The periodic refresh: changed states at once, period counts every :data:`ROW_PERIODS_EVERY` calls."""
        self._refreshes += 1
        self.show_rows(model, periods_too=self._refreshes % ROW_PERIODS_EVERY == 0)

    def show_progress(self, model: SweepModel, now: float) -> None:
        """The progress line: frequencies done, elapsed time, time to finish, the number of rows in each state."""
        counts: dict[str, int] = {}
        for row in model.rows.values():
            counts[row.state] = counts.get(row.state, 0) + 1
        summary = Text(f"{model.done}/{model.total} frequencies  elapsed {format_duration(model.elapsed(now))}  "
                       f"to finish {format_duration(model.eta(now))}  ")
        for name, count in counts.items():
            summary.append(f" {name} {count}", style=STATE_STYLES.get(name, ""))
        self.progress.update(summary, layout=False)
