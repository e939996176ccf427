"""`coartic inspect`: the summary of a recording, its errors, and the plot."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from coartic.cli import app

DATA = Path(__file__).parents[1] / "data/realdata"
EMA = DATA / "emu-ema-german/derived"


def test_inspect_ema_with_labels_and_plot(tmp_path: Path) -> None:
    png = tmp_path / "ch.png"
    r = CliRunner().invoke(app, [
        "inspect", str(EMA / "dfgspp_mo1_prosody_0024_ema.csv"),
        "--labels", str(EMA / "dfgspp_mo1_prosody_0024_Segment.tsv"),
        "--label-map", "german_sampa", "--plot", str(png)], env={"COLUMNS": "160"})
    assert r.exit_code == 0, r.output
    out = r.output
    assert "6 markers, 800 frames at 200 Hz" in out
    assert "ul: 3.810-3.995 s (38 frames) left missing (at the end)" in out
    assert "&p:" in out and "LR not available: no lip-corner sensor" in out
    assert "│ LA " in out or "LA " in out
    assert png.stat().st_size > 20_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_inspect_c3d_without_face_markers_and_bad_file(tmp_path: Path) -> None:
    r = CliRunner().invoke(app, ["inspect", str(DATA / "c3d-optotrak/Optotrak.c3d")],
                           env={"COLUMNS": "160"})
    assert r.exit_code == 2
    assert "truncated C3D: the header declares 1149 frames" in r.output
    assert "--allow-truncated" in " ".join(r.output.split())  # the option, not the Python keyword
    png = tmp_path / "m.png"
    r = CliRunner().invoke(app, ["inspect", str(DATA / "c3d-optotrak/Optotrak.c3d"),
                                 "--allow-truncated", "--plot", str(png)], env={"COLUMNS": "160"})
    # read, summarised and plotted, but no channel can be made of it: scripts must see that
    assert r.exit_code == 1, r.output
    assert png.is_file()
    assert "54 markers, 29 frames at 30 Hz" in r.output and "Marker_54" in r.output
    assert "no channels:" in r.output and "required marker(s)" in r.output
    assert png.read_bytes()[:4] == b"\x89PNG"
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,UL_x,UL_y,UL_z\n0,1,2,3\n0.01,1,x,3\n")
    r = CliRunner().invoke(app, ["inspect", str(bad)], env={"COLUMNS": "200"})
    assert r.exit_code == 2 and "line 3: column 'UL_y': 'x' is not a number" in r.output
    assert "Traceback" not in r.output


def test_inspect_plot_into_a_missing_folder_is_an_error_first(tmp_path: Path) -> None:
    r = CliRunner().invoke(app, ["inspect", str(EMA / "dfgspp_mo1_prosody_0024_ema.csv"),
                                 "--plot", str(tmp_path / "nodir" / "x.png")], env={"COLUMNS": "300"})
    assert r.exit_code == 2, r.output
    assert "error: --plot" in r.output and "nodir does not exist" in r.output
    assert "Traceback" not in r.output


def test_fit_channels_option_treats_la_like_the_others(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import coartic.jobs.fit as job

    spec = tmp_path / "s.toml"
    spec.write_text(f"""
[corpus]
files = ["{EMA / 'dfgspp_mo1_prosody_0024_ema.csv'}"]
labels = ["{EMA / 'dfgspp_mo1_prosody_0024_Segment.tsv'}"]
label_map = "german_sampa"
[model]
channels = ["LA"]
""")
    seen: list[tuple[str, ...]] = []

    def fit_job(s: Any, out: Path, **kw: Any) -> None:  # the option is what is tested, not the fit
        seen.append(s.channels)
        raise ValueError("stop here")

    monkeypatch.setattr(job, "fit_job", fit_job)
    for chans in ("JO", "LA,JO"):  # JO is not in the spec either: it may be named like LA
        r = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "o"), "--channels", chans])
        assert "stop here" in r.output, r.output
    r = CliRunner().invoke(app, ["fit", str(spec), "--out", str(tmp_path / "o"), "--channels", "XX"])
    assert r.exit_code != 0 and "--channels: ['XX']: not channels" in r.output
    assert seen == [("JO",), ("LA", "JO")]
