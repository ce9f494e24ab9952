"""Tests of bodebench.core.response (derived values, files) and bodebench.apps.plots."""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodebench.apps.plots import plot_bode, plot_periods
from bodebench.core.response import FrequencyResponse, ResponsePoint
from bodebench.io.results import ResultsError, ResultsWriter, load_response, save_response

HEADER = (
    "frequency_hz,harmonic,channel,amplitude,gain,gain_db,phase_deg,p,q,periods,converged,status,"
    "uncertainty,gain_ci,gain_db_ci,phase_ci_deg,uncertainty_1d,within_eps,periods_needed,thd,coherence,"
    "periods_discarded,drift_per_s,tolerance_percent"
)
HEAD = 0
"""Lines above the header of a response.csv (its description is beside it, in response.csv-metadata.json)."""


def point(
    p: float,
    q: float,
    *,
    f: float = 1.0,
    k: int = 1,
    channel: str = "position",
    amplitude: float = 1.0,
    periods: int = 10,
    converged: bool = True,
    status: str = "converged",
    uncertainty: float = math.nan,
) -> ResponsePoint:
    return ResponsePoint(f, k, channel, amplitude, p, q, periods, converged, status, uncertainty)


def paper_phase_deg(pc: float, qc: float) -> float:
    """docs/METHOD.md's piecewise phase formula (with 180/pi for the paper's 57.3), axes included."""
    deg = 180.0 / math.pi
    if pc == 0.0:
        sign = (qc > 0) - (qc < 0)
        return 180.0 * (-1.0 - 0.5 * sign)
    if pc > 0.0 and qc <= 0.0:
        return deg * math.atan(qc / pc)
    if pc < 0.0:
        return -180.0 + deg * math.atan(qc / pc)
    return -360.0 + deg * math.atan(qc / pc)  # pc > 0, qc > 0


def same_point(a: ResponsePoint, b: ResponsePoint) -> bool:
    for name in ("frequency_hz", "amplitude", "p", "q", "uncertainty"):
        x, y = getattr(a, name), getattr(b, name)
        if not (x == y or (math.isnan(x) and math.isnan(y))):
            return False
        if x == 0.0 and math.copysign(1.0, x) != math.copysign(1.0, y):
            return False
    return all(getattr(a, n) == getattr(b, n) for n in ("harmonic", "channel", "periods", "converged", "status"))


# ---------------------------------------------------------------- derived values


@pytest.mark.parametrize(
    ("p", "q", "expected"),
    [
        (1.0, -1.0, -45.0),  # P > 0, Q < 0
        (-1.0, -1.0, -135.0),  # P < 0, Q < 0
        (-1.0, 1.0, -225.0),  # P < 0, Q > 0
        (1.0, 1.0, -315.0),  # P > 0, Q > 0
        (math.sqrt(3.0), -1.0, -30.0),
        (1.0, math.sqrt(3.0), -300.0),
        (0.0, 2.0, -270.0),
        (0.0, -2.0, -90.0),
        (3.0, 0.0, 0.0),
        (-3.0, 0.0, -180.0),
    ],
)
def test_phase_hand_cases(p: float, q: float, expected: float) -> None:
    pt = point(p, q)
    assert pt.phase_deg == pytest.approx(expected, abs=1e-12)
    assert pt.phase_deg == pytest.approx(paper_phase_deg(p, q), abs=1e-12)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-1e6, 1e6, allow_nan=False).filter(lambda v: abs(v) > 1e-6 or v == 0.0),
    st.floats(-1e6, 1e6, allow_nan=False).filter(lambda v: abs(v) > 1e-6 or v == 0.0),
)
def test_phase_matches_paper_formula(p: float, q: float) -> None:
    if p == 0.0 and q == 0.0:
        return
    phase = point(p, q).phase_deg
    assert -360.0 < phase <= 0.0
    assert phase == pytest.approx(paper_phase_deg(p, q), abs=1e-9)


def test_phase_stays_inside_half_open_interval_for_tiny_lead() -> None:
    phase = point(1.0, 1e-300).phase_deg
    assert -360.0 < phase < -359.999


def test_gain_and_db_hand_case() -> None:
    pt = point(3.0, 4.0, amplitude=2.0)
    assert pt.gain == pytest.approx(2.5, rel=1e-15)
    assert pt.gain_db == pytest.approx(20.0 * math.log10(2.5), rel=1e-15)
    assert point(0.1, 0.0, amplitude=0.01).gain_db == pytest.approx(20.0, rel=1e-12)


def test_phase_nan_below_resolution_but_gain_kept() -> None:
    pt = point(1e-9, 2e-9, status="below_resolution", converged=False)
    assert math.isnan(pt.phase_deg)
    assert pt.gain == pytest.approx(math.sqrt(5.0) * 1e-9)
    assert np.isnan(FrequencyResponse([pt]).phase_deg[0])


def test_confidence_half_widths_hand_case() -> None:
    pt = point(3.0, 4.0, amplitude=2.0, uncertainty=1.0)
    assert pt.gain_ci == pytest.approx(0.5)
    assert pt.gain_db_ci == pytest.approx(20.0 * math.log10(6.0 / 5.0))
    assert pt.phase_ci_deg == pytest.approx(math.degrees(math.asin(0.2)))


def test_confidence_half_widths_match_disc_geometry() -> None:
    """Largest gain and angle deviation over the disc of radius u around c, found by sampling its boundary."""
    p, q, u, amplitude = -0.8, 0.35, 0.3, 0.5
    pt = point(p, q, amplitude=amplitude, uncertainty=u)
    theta = np.linspace(0.0, 2.0 * np.pi, 200_001)
    boundary = complex(p, q) + u * np.exp(1j * theta)
    max_gain_db = 20.0 * np.log10(np.abs(boundary).max() / abs(complex(p, q)))
    max_angle = np.degrees(np.abs(np.angle(boundary / complex(p, q))).max())
    assert pt.gain_db_ci == pytest.approx(max_gain_db, rel=1e-6)
    assert pt.phase_ci_deg == pytest.approx(max_angle, rel=1e-6)
    assert pt.gain_ci == pytest.approx(u / amplitude)


def test_confidence_when_uncertainty_swamps_coefficient() -> None:
    pt = point(0.3, -0.4, uncertainty=0.5)
    assert pt.gain_db_ci == math.inf
    assert pt.phase_ci_deg == 180.0
    unknown = point(0.3, -0.4)
    assert math.isnan(unknown.gain_ci) and math.isnan(unknown.gain_db_ci) and math.isnan(unknown.phase_ci_deg)


def test_complex_response_angle_and_magnitude_agree_with_phase_and_gain() -> None:
    pts = [point(p, q, f=i + 1.0, amplitude=0.5) for i, (p, q) in enumerate([(1, -2), (-3, -1), (-2, 5), (4, 1)])]
    fr = FrequencyResponse(pts)
    g = fr.complex_response()
    assert np.allclose(np.abs(g), fr.gain, rtol=1e-14)
    assert np.allclose(np.mod(np.degrees(np.angle(g)) - fr.phase_deg + 180.0, 360.0) - 180.0, 0.0, atol=1e-9)
    assert g[0] == complex(1, -2) / 0.5


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        ("amplitude", {"amplitude": 0.0}),
        ("amplitude", {"amplitude": math.nan}),
        ("frequency_hz", {"f": -1.0}),
        ("harmonic", {"k": 0}),
        ("periods", {"periods": -1}),
        ("channel", {"channel": "pos,ition"}),
        ("status", {"status": ""}),
        ("uncertainty", {"uncertainty": -0.1}),
    ],
)
def test_bad_point_fields_raise_naming_field(field: str, kwargs: dict) -> None:
    with pytest.raises(ValueError, match=field):
        point(1.0, 1.0, **kwargs)


# ---------------------------------------------------------------- collection


def test_select_filters_and_sorts_by_frequency() -> None:
    pts = [
        point(1, 0, f=5.0, k=1, channel="position"),
        point(1, 0, f=1.0, k=2, channel="position"),
        point(1, 0, f=2.0, k=1, channel="velocity"),
        point(1, 0, f=0.5, k=1, channel="position"),
    ]
    fr = FrequencyResponse(pts, config={"eps_percent": 0.01}, case="c1")
    assert fr.harmonics == (1, 2)
    assert fr.channels == ("position", "velocity")
    sel = fr.select(harmonic=1, channel="position")
    assert list(sel.frequency_hz) == [0.5, 5.0]
    assert sel.case == "c1" and sel.config == {"eps_percent": 0.01}
    assert list(fr.select(harmonic=1).frequency_hz) == [0.5, 2.0, 5.0]
    assert len(fr.select(channel="nothing")) == 0
    assert len(fr) == 4 and list(fr) == pts


def test_unwrap_across_the_fold_boundary() -> None:
    true_phase = np.linspace(-300.0, -420.0, 13)  # crosses -360, where the folded phase jumps to near 0
    freqs = np.geomspace(1.0, 100.0, 13)
    pts = [
        point(math.cos(math.radians(ph)), math.sin(math.radians(ph)), f=float(f))
        for f, ph in zip(freqs, true_phase, strict=False)
    ]
    fr = FrequencyResponse(pts)
    folded = fr.phase_deg
    assert folded.max() > -60.0 and folded.min() < -300.0  # the jump is really there
    assert np.allclose(fr.phase_unwrapped_deg(), true_phase, atol=1e-9)


def test_unwrap_downward_lag_keeps_nan_and_input_order() -> None:
    true_phase = np.array([-10.0, -100.0, -170.0, -250.0, -340.0, -400.0, -470.0, -560.0])
    freqs = np.arange(1.0, 9.0)
    status = ["converged"] * 8
    status[3] = "below_resolution"
    pts = [
        point(math.cos(math.radians(ph)), math.sin(math.radians(ph)), f=float(f), status=s)
        for f, ph, s in zip(freqs, true_phase, status, strict=False)
    ]
    order = [5, 2, 7, 0, 3, 1, 6, 4]
    fr = FrequencyResponse([pts[i] for i in order])
    unwrapped = fr.phase_unwrapped_deg()
    expected = true_phase[order]
    defined = np.array(status)[order] != "below_resolution"
    assert np.isnan(unwrapped[~defined]).all()
    assert np.allclose(unwrapped[defined], expected[defined], atol=1e-9)


def test_unwrap_rejects_mixed_selection() -> None:
    fr = FrequencyResponse([point(1, 0, k=1), point(1, 0, k=2)])
    with pytest.raises(ValueError, match="select"):
        fr.phase_unwrapped_deg()
    fr2 = FrequencyResponse([point(1, 0, channel="a"), point(1, 0, channel="b")])
    with pytest.raises(ValueError):
        fr2.phase_unwrapped_deg()
    assert fr.select(harmonic=2).phase_unwrapped_deg().shape == (1,)


# ---------------------------------------------------------------- files


def sample_response() -> FrequencyResponse:
    pts = [
        point(0.1 + 0.2, -1.0 / 3.0, f=1.3, amplitude=0.01, uncertainty=1e-7),
        point(-2.5e-300, 7.123456789012345e-5, f=10.03, k=2, periods=12345, converged=False, status="capped"),
        point(1e-12, -3e-12, f=100.0, status="below_resolution", converged=False, uncertainty=5e-12),
        point(0.0, -0.0, f=7.0, channel="velocity", status="failed", converged=False),
        point(math.nan, math.nan, f=8.0, status="failed", converged=False),
        point(-0.0, 1.0, f=9.0, uncertainty=0.0),
    ]
    config = {"frequencies_hz": (1.0, 1.3, 2.0), "eps_percent": 0.01, "rule": {"name": "full", "n_k": 1}, "x": None}
    return FrequencyResponse(pts, config=config, case="friction Fbar=0.8")


def test_save_load_round_trip_is_exact(tmp_path: Path) -> None:
    fr = sample_response()
    save_response(fr, tmp_path / "run")
    back = load_response(tmp_path / "run")
    assert len(back) == len(fr)
    assert all(same_point(a, b) for a, b in zip(fr, back, strict=False))
    assert back.case == fr.case
    assert back.config == {
        "frequencies_hz": [1.0, 1.3, 2.0],
        "eps_percent": 0.01,
        "rule": {"name": "full", "n_k": 1},
        "x": None,
    }
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["response.csv", "response.csv-metadata.json",
                                                                     "response.json"]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(1e-3, 1e4),
            st.floats(-1e3, 1e3, allow_nan=False),
            st.floats(-1e3, 1e3, allow_nan=False),
            st.floats(1e-6, 1e2),
            st.integers(1, 5),
        ),
        max_size=8,
    )
)
def test_round_trip_property(tmp_path_factory: pytest.TempPathFactory, rows: list) -> None:
    directory = tmp_path_factory.mktemp("rt")
    fr = FrequencyResponse(point(p, q, f=f, amplitude=a, k=k) for f, p, q, a, k in rows)
    save_response(fr, directory)
    back = load_response(directory)
    assert all(same_point(a, b) for a, b in zip(fr, back, strict=False)) and len(back) == len(fr)


def test_csv_layout(tmp_path: Path) -> None:
    fr = FrequencyResponse([point(3.0, 4.0, amplitude=2.0, periods=7, converged=False, status="capped")])
    save_response(fr, tmp_path)
    lines = (tmp_path / "response.csv").read_text().splitlines()
    assert lines[HEAD] == HEADER
    cells = dict(zip(HEADER.split(","), lines[HEAD + 1].split(","), strict=False))
    assert float(cells["gain"]) == pytest.approx(2.5)
    assert cells["converged"] == "false" and cells["status"] == "capped" and cells["periods"] == "7"
    assert cells["uncertainty"] == "nan"
    assert float(cells["phase_deg"]) == pytest.approx(paper_phase_deg(3.0, 4.0))


def test_sidecar_content(tmp_path: Path) -> None:
    save_response(sample_response(), tmp_path)
    data = json.loads((tmp_path / "response.json").read_text())
    assert data["format"] == "bodebench-response" and data["version"] == 6
    assert data["case"] == "friction Fbar=0.8"
    assert data["config"]["frequencies_hz"] == [1.0, 1.3, 2.0]
    assert data["software"]["name"] == "bodebench" and isinstance(data["software"]["version"], str)


def rows(points: list[ResponsePoint]) -> list[tuple[float, int, str, float, float, int, str]]:
    """What identifies a point in a file (NaN uncertainties compare unequal to themselves)."""
    return [(p.frequency_hz, p.harmonic, p.channel, p.p, p.q, p.periods, p.status) for p in points]


def test_the_writer_appends_and_syncs_each_point(tmp_path: Path) -> None:
    writer = ResultsWriter(tmp_path / "out", "live", {"analysis": {"harmonics": [1]}})
    points = [point(1.0, -float(i), f=1.0 + i) for i in range(3)]
    for i, pt in enumerate(points):
        writer.append([pt])
        back = load_response(tmp_path / "out")
        assert rows(back.points) == rows(points[: i + 1]) and back.case == "live"
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.endswith(".tmp")]


def test_a_row_an_interrupted_append_left_is_not_read_and_resuming_cuts_it(tmp_path: Path) -> None:
    points = [point(1.0, -float(i), f=1.0 + i) for i in range(3)]
    reference = ResultsWriter(tmp_path / "reference", "live", {})
    reference.append(points)
    expected = reference.path.read_bytes()
    ResultsWriter(tmp_path, "live", {}).append(points[:2])
    whole = (tmp_path / "response.csv").read_bytes()
    row = whole.split(b"\n")[-2]
    for cut in (1, len(row) // 2, len(row) - 20):  # torn inside the first, a middle and a derived column
        (tmp_path / "response.csv").write_bytes(whole + row[:cut])
        with pytest.raises(ResultsError, match=rf"response\.csv: line {HEAD + 4}: unterminated row"):
            load_response(tmp_path)
        assert rows(load_response(tmp_path, drop_torn_row=True).points) == rows(points[:2])
        ResultsWriter(tmp_path, "live", {}, resume=True).append(points[2:])
        assert rows(load_response(tmp_path).points) == rows(points)
        assert (tmp_path / "response.csv").read_bytes() == expected
    # a whole last row without its newline (an editor's doing) is read, and resuming ends it
    (tmp_path / "response.csv").write_bytes(whole[:-1])
    assert rows(load_response(tmp_path).points) == rows(points[:2])
    ResultsWriter(tmp_path, "live", {}, resume=True).append(points[2:])
    assert rows(load_response(tmp_path).points) == rows(points)


def test_config_must_be_json_serialisable() -> None:
    with pytest.raises(ValueError, match="bad"):
        FrequencyResponse(config={"bad": object()})


def _replace_cell(csv_path: Path, line: int, column: str, value: str) -> None:
    """Replace a cell of ``line`` counted from the header (line 1)."""
    line += HEAD
    lines = csv_path.read_text().split("\n")
    cells = lines[line - 1].split(",")
    cells[HEADER.split(",").index(column)] = value
    lines[line - 1] = ",".join(cells)
    csv_path.write_text("\n".join(lines))


@pytest.mark.parametrize("column", ["gain", "gain_db", "phase_deg", "gain_ci", "phase_ci_deg"])
def test_tampered_derived_column_names_file_line_column(tmp_path: Path, column: str) -> None:
    save_response(sample_response(), tmp_path)
    _replace_cell(tmp_path / "response.csv", 2, column, "0.123")
    with pytest.raises(ResultsError) as info:
        load_response(tmp_path)
    message = str(info.value)
    assert "response.csv" in message and f"line {HEAD + 2}:" in message and repr(column) in message


def test_derived_within_tolerance_accepted(tmp_path: Path) -> None:
    save_response(FrequencyResponse([point(3.0, 4.0, amplitude=2.0)]), tmp_path)
    _replace_cell(tmp_path / "response.csv", 2, "gain", repr(2.5 * (1 + 1e-11)))
    assert load_response(tmp_path).points[0].gain == pytest.approx(2.5)


def test_unparsable_number_names_column(tmp_path: Path) -> None:
    save_response(sample_response(), tmp_path)
    _replace_cell(tmp_path / "response.csv", 3, "p", "1.2.3")
    with pytest.raises(ResultsError, match=rf"line {HEAD + 3}:.*'p'"):
        load_response(tmp_path)


def test_truncated_csv(tmp_path: Path) -> None:
    save_response(sample_response(), tmp_path)
    csv_path = tmp_path / "response.csv"
    text = csv_path.read_text()
    csv_path.write_text(text[: len(text) - 25])
    with pytest.raises(ResultsError, match=rf"response\.csv: line {HEAD + 7}"):
        load_response(tmp_path)


def test_bad_header(tmp_path: Path) -> None:
    save_response(sample_response(), tmp_path)
    csv_path = tmp_path / "response.csv"
    csv_path.write_text(csv_path.read_text().replace("gain_db,", "gain_dB,", 1))
    with pytest.raises(ResultsError, match=rf"line {HEAD + 1}:.*gain_dB"):
        load_response(tmp_path)


def test_missing_files(tmp_path: Path) -> None:
    save_response(sample_response(), tmp_path)
    (tmp_path / "response.json").unlink()
    with pytest.raises(ResultsError, match=r"response\.json"):
        load_response(tmp_path)
    with pytest.raises(ResultsError, match="not found"):
        load_response(tmp_path / "nowhere")
    save_response(sample_response(), tmp_path)
    (tmp_path / "response.csv").unlink()
    with pytest.raises(ResultsError, match=r"response\.csv"):
        load_response(tmp_path)


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        (json.dumps({"format": "other", "version": 1, "case": "", "config": {}}), "'format'"),
        (json.dumps({"format": "bodebench-response", "version": 7, "case": "", "config": {}}), "'version'"),
        (json.dumps({"format": "bodebench-response", "version": 1, "case": ""}), "'config'"),
    ],
)
def test_bad_sidecar(tmp_path: Path, content: str, fragment: str) -> None:
    save_response(sample_response(), tmp_path)
    (tmp_path / "response.json").write_text(content)
    with pytest.raises(ResultsError) as info:
        load_response(tmp_path)
    assert "response.json" in str(info.value) and fragment in str(info.value)


# ---------------------------------------------------------------- plots


def _second_order(case: str, zeta: float) -> FrequencyResponse:
    fr = FrequencyResponse(case=case)
    for k in (1, 2):
        for i, f in enumerate(np.geomspace(1.0, 100.0, 15)):
            g = 1.0 / (1.0 - (f / 10.0) ** 2 + 2j * zeta * f / 10.0) / k**2
            status = "capped" if i == 7 else ("below_resolution" if (k == 2 and i == 3) else "converged")
            fr.add(
                point(
                    g.real * 0.01,
                    g.imag * 0.01,
                    f=float(f),
                    k=k,
                    amplitude=0.01,
                    periods=10 + 5 * i,
                    converged=status == "converged",
                    status=status,
                    uncertainty=abs(g) * 0.01 * (0.05 if i != 5 else 2.0),
                )
            )
    return fr


def _check_images(paths: list[Path], stem: Path) -> None:
    assert paths == [Path(f"{stem}.png"), Path(f"{stem}.svg")]
    png, svg = paths
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 1000
    assert "<svg" in svg.read_text()


def test_plot_bode_writes_png_and_svg(tmp_path: Path) -> None:
    stem = tmp_path / "plots" / "bode"
    paths = plot_bode({"zeta 0.05": _second_order("a", 0.05), "zeta 0.5": _second_order("b", 0.5)}, stem, "Bode",
                      formats=("png", "svg"))
    _check_images(paths, stem)
    single = plot_bode(_second_order("one", 0.2), tmp_path / "single", formats=("png", "svg"))
    _check_images(single, tmp_path / "single")
    assert plot_bode(_second_order("one", 0.2), tmp_path / "default") == [tmp_path / "default.png"]


def test_plot_periods_writes_png_and_svg(tmp_path: Path) -> None:
    stem = tmp_path / "periods"
    _check_images(plot_periods({"a": _second_order("a", 0.05)}, stem, title="Periods", formats=("PNG", "svg")), stem)
    with pytest.raises(ValueError, match="plot format jpg unknown"):
        plot_periods({"a": _second_order("a", 0.05)}, stem, formats=("png", "jpg"))


def test_plots_reject_empty_input(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="nothing to plot"):
        plot_bode(FrequencyResponse(), tmp_path / "x")
    with pytest.raises(ValueError, match="FrequencyResponse"):
        plot_periods({"a": [1, 2]}, tmp_path / "x")  # type: ignore[dict-item]


def test_a_version_1_results_file_still_loads(tmp_path: Path) -> None:
    """Files written before the added columns load, the new fields taking their defaults."""
    response = sample_response()
    save_response(response, tmp_path)
    csv = tmp_path / "response.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(",".join(line.split(",")[:16]) for line in lines) + "\n")
    sidecar = json.loads((tmp_path / "response.json").read_text())
    sidecar["version"] = 1
    (tmp_path / "response.json").write_text(json.dumps(sidecar))
    loaded = load_response(tmp_path)
    assert [repr((p.p, p.q)) for p in loaded.points] == [repr((p.p, p.q)) for p in response.points]
    assert all(math.isnan(p.uncertainty_1d) and not p.within_eps and p.periods_needed == 0 for p in loaded.points)


def test_an_out_that_is_a_dangling_link_or_a_file_is_one_line_naming_it(tmp_path: Path) -> None:
    from bodebench.io.results import check_output

    link = tmp_path / "out"
    link.symlink_to(tmp_path / "nowhere")
    with pytest.raises(ResultsError, match=r"out: a symbolic link to .*nowhere, which does not exist"):
        check_output(link, 10)
    assert not (tmp_path / "nowhere").exists()
    afile = tmp_path / "afile"
    afile.write_text("")
    with pytest.raises(ResultsError, match=r"afile: not a directory"):
        check_output(afile, 10)
