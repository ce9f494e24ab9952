"""Results that describe themselves: the CSV's description beside it, its delimiter and decimal mark, and the record
of every run in the sidecar."""

from __future__ import annotations

import csv
import json
import math
import socket
import uuid
from datetime import datetime
from importlib import metadata
from pathlib import Path

import pytest
from helpers import interrupt_after

from bodebench.apps.cli import main
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.config import ConfigError, parse_config
from bodebench.io.csvstyle import COLUMN_DOCS
from bodebench.io.results import CSV_COLUMNS, CSV_METADATA_NAME, ResultsWriter, load_response, save_response

OFFLINE = """title = "A lag"
[plant]
model = "lag"
time_constant = 0.05
[excitation]
amplitude = 1.0
frequencies_hz = [0.5, 2.0, 8.0]
[analysis]
tolerance_percent = 0.5
steps_per_period = 32
"""


def points() -> list[ResponsePoint]:
    return [ResponsePoint(f, k, "position", 0.25, 0.1 / f / k, -0.05 / k, 40, True, "converged",
                          uncertainty=1e-5, uncertainty_1d=8e-6, thd=0.012 if k == 1 else math.nan,
                          coherence=0.99)
            for f in (1.5, 12.25) for k in (1, 2)]


def data_lines(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if not line.startswith("#")]


def test_the_csv_is_a_plain_table_and_its_description_states_every_column(tmp_path: Path) -> None:
    """response.csv opens with pandas' defaults (the header its first line, each column's type as written); the
    CSVW description beside it names every column with its meaning and the confidence level."""
    import pandas as pd

    save_response(FrequencyResponse(points(), config={}), tmp_path)
    text = (tmp_path / "response.csv").read_text()
    assert text.splitlines()[0] == ",".join(CSV_COLUMNS)
    table = pd.read_csv(tmp_path / "response.csv")
    assert list(table.columns) == list(CSV_COLUMNS) and len(table) == len(points())
    assert table["frequency_hz"].tolist() == [p.frequency_hz for p in points()]
    assert table["p"].tolist() == [p.p for p in points()] and table["converged"].dtype == bool
    meta = json.loads((tmp_path / CSV_METADATA_NAME).read_text())
    assert meta["url"] == "response.csv" and meta["dialect"]["delimiter"] == ","
    assert "95% confidence" in meta["dc:description"]
    columns = meta["tableSchema"]["columns"]
    assert [c["name"] for c in columns] == list(CSV_COLUMNS)
    assert {c["name"]: c["dc:description"] for c in columns} == COLUMN_DOCS
    assert load_response(tmp_path).points == points()


def test_a_file_of_the_previous_format_with_its_comment_block_loads_and_resumes_into_a_plain_table(
        tmp_path: Path) -> None:
    save_response(FrequencyResponse(points()[:2], config={}), tmp_path)
    csv_path = tmp_path / "response.csv"
    lines = csv_path.read_text().splitlines()
    old = ["# bodebench response, format 5: one row per frequency, harmonic and channel, in the order measured",
           "# every interval and uncertainty is at 95% confidence", *lines]
    csv_path.write_text("\n".join(old) + "\n")
    (tmp_path / CSV_METADATA_NAME).unlink()
    assert load_response(tmp_path).points == points()[:2]
    writer = ResultsWriter(tmp_path, "c", {}, resume=True)
    writer.append(points()[2:])
    assert csv_path.read_text().splitlines()[0] == ",".join(CSV_COLUMNS)
    assert (tmp_path / CSV_METADATA_NAME).exists()
    assert load_response(tmp_path).points == points()


@pytest.mark.parametrize(("delimiter", "char", "decimal"), [(";", ";", ","), ("tab", "\t", ","), (";", ";", ".")])
def test_a_delimiter_and_decimal_mark_for_comma_decimal_locales(tmp_path: Path, delimiter: str, char: str,
                                                                decimal: str) -> None:
    """The file reads back exactly, and Python's csv module (as a spreadsheet would) finds the columns, the
    numbers written with the decimal mark."""
    config = {"results": {"delimiter": delimiter, "decimal": decimal}}
    writer = ResultsWriter(tmp_path, "c", config)
    writer.append(points()[:2])
    writer.append(points()[2:])
    assert load_response(tmp_path).points == points()
    rows = list(csv.reader(data_lines(tmp_path / "response.csv"), delimiter=char))
    assert rows[0] == list(CSV_COLUMNS)
    first = dict(zip(rows[0], rows[1], strict=True))
    assert float(first["frequency_hz"].replace(decimal, ".")) == 1.5
    assert ("," in first["amplitude"]) == (decimal == ",")
    assert float(first["thd"].replace(",", ".")) == 0.012
    # a resumed sweep goes on in the same style
    ResultsWriter(tmp_path, "c", config, resume=True).append(points()[:1])
    assert len(load_response(tmp_path)) == 5


def test_the_results_table_is_validated() -> None:
    base = {"plant": {"model": "lag"}, "excitation": {"amplitude": 1.0, "frequencies_hz": [1.0]}}
    with pytest.raises(ConfigError, match=r'^x.toml: results.decimal: "," needs results.delimiter = ";" or "tab"'):
        parse_config({**base, "results": {"decimal": ","}}, "x.toml")
    with pytest.raises(ConfigError, match=r'^x.toml: results.delimiter: must be one of ",", ";", "tab", got "\|"$'):
        parse_config({**base, "results": {"delimiter": "|"}}, "x.toml")
    with pytest.raises(ConfigError, match=r"^x.toml: results.sep: unknown key"):
        parse_config({**base, "results": {"sep": ";"}}, "x.toml")


def test_each_run_is_recorded_and_a_resumed_sweep_adds_its_own(tmp_path: Path) -> None:
    config = tmp_path / "lag.toml"
    config.write_text(OFFLINE)
    out = tmp_path / "out"
    assert main(["simulate", str(config), "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    (run,) = json.loads((out / "response.json").read_text())["runs"]
    started, ended = datetime.fromisoformat(run["started"]), datetime.fromisoformat(run["ended"])
    assert started <= ended and run["duration_s"] == pytest.approx((ended - started).total_seconds(), abs=2e-3)
    assert run["software"]["version"] == metadata.version("bodebench")
    assert run["host"]["name"] == socket.gethostname()
    assert run["link"] == {"kind": "offline", "plant": "lag"}
    assert run["points"] == 3 and run["resumed"] is False and run["completed"] is True
    # an interrupted sweep: the last frequency's row lost; --resume measures it and adds a record
    interrupt_after(out, 2)
    assert main(["simulate", str(config), "--out", str(out), "--jobs", "1", "--quiet", "--resume"]) == 0
    first, second = json.loads((out / "response.json").read_text())["runs"]
    assert first == run and second["resumed"] is True and second["points"] == 3
    assert datetime.fromisoformat(second["started"]) >= ended


def test_a_bench_run_records_its_link_and_bus(tmp_path: Path) -> None:
    channel = f"selfdesc-{uuid.uuid4().hex[:8]}"
    config = tmp_path / "bench.toml"
    config.write_text(f"""
[plant]
model = "lag"
time_constant = 0.01
[excitation]
amplitude = 0.01
frequencies_hz = [5.0, 20.0]
[analysis]
tolerance_percent = 0.5
[bench]
transport = "can"
rate_hz = 1000
worker = "thread"
[can]
interface = "virtual"
channel = "{channel}"
[safety]
max_amplitude = 0.02
[simulator]
[results]
delimiter = ";"
decimal = ","
""")
    out = tmp_path / "out"
    assert main(["run", str(config), "--out", str(out), "--quiet"]) == 0
    (run,) = json.loads((out / "response.json").read_text())["runs"]
    assert run["link"]["kind"] == "bus" and run["link"]["interface"] == "virtual"
    assert run["link"]["channel"] == channel and run["link"]["clock"] == "lockstep"
    assert run["bus"]["frames_in"] > 0 and run["bus"]["frames_out"] > 0 and run["bus"]["lost_samples"] == 0
    assert run["pacing"] == "lockstep clock (no pacing)" and run["round_trip_s"] > 0
    assert run["completed"] is True and run["ended_by"] == "sweep complete"
    assert data_lines(out / "response.csv")[0] == ";".join(CSV_COLUMNS)
    assert len(load_response(out)) == 2
