"""EMA channels on a made-up recording whose channels are known (docs/DATA.md, EMA table)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic.io import DataError, load_trial

RATE = 250.0


def _write(path: Path, sensors: dict[str, np.ndarray], extra: str = "") -> None:
    n = next(iter(sensors.values())).shape[0]
    cols = ["time_s"] + [f"{s}_pos{a}" for s in sensors for a in "xyz"] + [f"{s}_orix" for s in
                                                                          sensors]
    with open(path, "w") as f:
        f.write(extra)
        f.write(",".join(cols) + "\n")
        for i in range(n):
            vals = [repr(float(v)) for s in sensors for v in sensors[s][i]] + ["0.5"] * len(sensors)
            f.write(",".join([repr(i / RATE), *vals]) + "\n")


@pytest.mark.filterwarnings("ignore::coartic.io.errors.DataWarning")  # made-up sizes (LR 480 mm)
def test_ema_channels_follow_the_documented_mapping(tmp_path: Path) -> None:
    n = 200
    t = np.arange(n) / RATE
    move = np.where(t < 0.1, 0.0, np.sin(2 * np.pi * 2 * (t - 0.1)))
    # axes of this system: x up, y lateral, z BACKWARDS (so anterior is -z)
    ul = np.stack([5.0 + 1.0 * move, np.full(n, 0.2), -8.0 + 0.5 * move], axis=1)
    ll = np.stack([-15.0 - 6.0 * move, np.full(n, -0.2), -6.0 - 1.0 * move], axis=1)
    jaw = np.stack([-25.0 - 4.0 * move, np.zeros(n), 5.0 * np.ones(n)], axis=1)
    lc = np.stack([-5.0 * np.ones(n), 24.0 + 2.0 * move, np.zeros(n)], axis=1)
    nose = np.stack([40.0 * np.ones(n), np.zeros(n), -20.0 * np.ones(n)], axis=1)
    p = tmp_path / "ema.csv"
    _write(p, {"UpperLip": ul, "LowerLip": ll, "JawS": jaw, "Corner": lc, "nz": nose},
           extra="# units: cm\n")
    roles = {"UL": "UpperLip", "LL": "LowerLip", "JAW": "JawS", "LC": "Corner",
             "axes": {"vertical": "+x", "anterior": "-z"}}
    ch = load_trial(p, role_map=roles).channels(rest_frames=25)  # rest: the still first 0.1 s
    mm = 10.0
    y0 = (5.0 + -15.0) / 2 * mm
    np.testing.assert_allclose(ch["ULO"], ul[:, 0] * mm - y0, atol=1e-9)
    np.testing.assert_allclose(ch["LLO"], y0 - ll[:, 0] * mm, atol=1e-9)
    np.testing.assert_allclose(ch["ULP"], -ul[:, 2] * mm, atol=1e-9)
    np.testing.assert_allclose(ch["LLP"], -ll[:, 2] * mm, atol=1e-9)
    np.testing.assert_allclose(ch["JO"], -jaw[:, 0] * mm, atol=1e-9)
    np.testing.assert_allclose(ch["LR"], 2 * np.abs(lc[:, 1]) * mm, atol=1e-9)
    np.testing.assert_allclose(ch["LA"], np.linalg.norm(ul - ll, axis=1) * mm, atol=1e-9)
    assert all(v.all() for v in ch.valid.values()) and set(ch.unavailable) == {"TTH", "TTA", "TBH", "TBA"}
    # a NOSE sensor makes JO the NOSE-JAW distance, as for marker sets
    ch2 = load_trial(p, role_map={**roles, "NOSE": "nz"}).channels(rest_frames=25)
    np.testing.assert_allclose(ch2["JO"], np.linalg.norm(nose - jaw, axis=1) * mm, atol=1e-9)
    # asking for LR without a corner sensor is an error naming the reason
    no_lc = {k: v for k, v in roles.items() if k != "LC"}
    with pytest.raises(DataError, match=r"channel LR cannot be computed: no lip-corner sensor"):
        load_trial(p, role_map=no_lc).channels(["LR"])


def test_ema_sensor_guess_and_missing_lips(tmp_path: Path) -> None:
    n = 50
    z = np.zeros((n, 3)) + 1.0
    p = tmp_path / "guess.csv"
    _write(p, {"upper_lip": z, "lower_lip": z - 10, "jaw": z - 20})
    t = load_trial(p)
    assert dict(t.roles.roles) == {"UL": "upper_lip", "LL": "lower_lip", "JAW": "jaw"}
    assert any("sensors guessed by name (UL=upper_lip, LL=lower_lip, JAW=jaw)" in n
               for n in t.meta["notes"])
    q = tmp_path / "tongue.csv"
    _write(q, {"tt": z, "tb": z})
    with pytest.raises(DataError, match=r"tongue\.csv: EMA channels need the UL and LL roles; the "
                                        r"sensors are \['tt', 'tb'\]"):
        load_trial(q).channels()


REAL = Path(__file__).parents[1] / "data/realdata/emu-ema-german/derived"


def test_tongue_channels_are_heights_and_advancements_from_rest(tmp_path: Path) -> None:
    n = 150
    t = np.arange(n) / RATE
    move = np.where(t < 0.1, 0.0, np.sin(2 * np.pi * 3 * (t - 0.1)))
    ul = np.stack([np.zeros(n), -9.0 + 0 * move, 0.5 + move], axis=1)
    ll = np.stack([np.zeros(n), -7.0 + 0 * move, -15.0 - 3 * move], axis=1)
    # up = +z, forwards = -y (the default axes); the tip rises 4 mm and moves back 2 mm, the body
    # lowers 3 mm and moves forwards 1 mm, each from its own rest position
    tt = np.stack([np.zeros(n), 11.0 + 2.0 * move, -4.0 + 4.0 * move], axis=1)
    tb = np.stack([np.zeros(n), 50.0 - 1.0 * move, 4.0 - 3.0 * move], axis=1)
    p = tmp_path / "tongue.csv"
    _write(p, {"ul": ul, "ll": ll, "t_tip": tt, "t_back": tb})
    trial = load_trial(p)
    assert dict(trial.roles.roles) == {"UL": "ul", "LL": "ll", "TT": "t_tip", "TB": "t_back"}
    ch = trial.channels(rest_frames=25)
    np.testing.assert_allclose(ch["TTH"], 4.0 * move, atol=1e-9)
    np.testing.assert_allclose(ch["TTA"], -2.0 * move, atol=1e-9)
    np.testing.assert_allclose(ch["TBH"], -3.0 * move, atol=1e-9)
    np.testing.assert_allclose(ch["TBA"], 1.0 * move, atol=1e-9)
    # without a TB sensor the body channels say why; asked for by name, an error naming it
    q = tmp_path / "tip_only.csv"
    _write(q, {"ul": ul, "ll": ll, "tt": tt})
    ch = load_trial(q).channels()
    assert "TTH" in ch and ch.unavailable["TBH"] == "no tongue-body sensor (role TB)"
    with pytest.raises(DataError, match=r"channel TBA cannot be computed: no tongue-body sensor"):
        load_trial(q).channels(["TTH", "TBA"])


def test_tongue_channels_are_refused_by_name_on_face_markers(tmp_path: Path) -> None:
    from coartic.io.trial import Trial

    markers = np.zeros((10, 2, 3))
    markers[:, 1, 1] = -10.0
    trial = Trial(markers=markers, marker_names=("UL", "LL"), rate=100.0, source=tmp_path / "m.csv")
    with pytest.raises(DataError, match=r"m\.csv: channel TTH cannot be computed: tongue channels "
                                        r"come from EMA tongue sensors \(roles TT, TB\)"):
        trial.channels(["LA", "TTH"])
    assert "TTH" in trial.channels().unavailable


def _x_anterior_copy(tmp_path: Path) -> tuple[Path, Path]:
    """The real German EMA (up +z, forwards -y) rewritten with x forwards, y lateral, z up."""
    src = REAL / "dfgspp_mo1_prosody_0020_ema.csv"
    lines = src.read_text().splitlines()
    header = lines[0].split(",")
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        for s in ("ul", "ll", "jw", "tt", "tm", "tb"):
            ix, iy = header.index(f"{s}_posx"), header.index(f"{s}_posy")
            x, y = cells[ix], cells[iy]
            cells[ix] = "" if y == "" else repr(-float(y)) if float(y) else "0.0"
            cells[iy] = x
        out.append(",".join(cells))
    p = tmp_path / "x_anterior.csv"
    p.write_text("\n".join(out) + "\n")
    return src, p


def test_ema_axes_from_the_spec_and_a_warning_when_they_look_wrong(tmp_path: Path) -> None:
    import warnings

    from typer.testing import CliRunner

    from coartic.cli import app
    from coartic.fit.data import load_utterances
    from coartic.fit.spec import load_spec
    from coartic.io.errors import DataWarning

    src, p = _x_anterior_copy(tmp_path)
    truth = load_trial(src).channels()
    with pytest.warns(DataWarning, match=r"x_anterior\.csv: the EMA axes look wrong .*LL is 11\.\d mm "
                                         r"from the jaw sensor along x \(taken as lateral\)"):
        load_trial(p).channels()
    axes = {"UL": "ul", "LL": "ll", "JAW": "jw", "axes": {"vertical": "+z", "anterior": "+x"}}
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # the right axes: no warning
        right = load_trial(p, role_map=axes).channels()
    for c in ("ULP", "LLP", "ULO", "LA", "JO"):
        np.testing.assert_allclose(right[c], truth[c], atol=1e-9, err_msg=c)
    # the fit spec's role map carries the axes too
    spec = tmp_path / "spec.toml"
    spec.write_text(f"""
[corpus]
files = ["{p}"]
labels = ["{REAL / 'dfgspp_mo1_prosody_0020_Segment.tsv'}"]
label_map = "german_sampa"
role_map = {{ UL = "ul", LL = "ll", JAW = "jw", axes = {{ vertical = "+z", anterior = "+x" }} }}
[model]
channels = ["ULP", "LLP"]
""")
    utt = load_utterances(load_spec(spec))[0]
    np.testing.assert_allclose(utt.observed["LLP"], truth["LLP"], atol=1e-9)
    spec.write_text(spec.read_text().replace('anterior = "+x"', 'lateral = "+y"'))
    from coartic.errors import SpecError

    with pytest.raises(SpecError, match=r"\[corpus\.role_map\] role map: unknown axis 'lateral'"):
        load_spec(spec)
    # the CLI prints the warning
    r = CliRunner().invoke(app, ["inspect", str(p)], env={"COLUMNS": "200"})
    assert r.exit_code == 0, r.output
    assert "warning: " in r.output and "the EMA axes look wrong" in " ".join(r.output.split())


def test_role_map_giving_two_roles_one_sensor_is_refused(tmp_path: Path) -> None:
    from coartic.io.roles import RoleMap

    with pytest.raises(DataError, match=r"roles UL and LL both name marker 'ul'"):
        RoleMap.from_dict({"UL": "ul", "LL": "ul"})
    # LL given the marker that UL finds by its own name: LA would be 0
    with pytest.raises(DataError, match=r"0020_ema\.csv: roles UL and LL are both marker 'ul'"):
        load_trial(REAL / "dfgspp_mo1_prosody_0020_ema.csv", role_map={"LL": "ul"}).channels()


def test_emu_bundle_char_positions_and_deep_nesting(tmp_path: Path) -> None:
    import base64
    import json

    header = ("SSFF -- (c) SHLRC\nMachine IBM-PC\nRecord_Freq 100.0\nStart_Time 0.0\n"
              "Column ul_posx CHAR 1\nColumn ul_posy CHAR 1\nColumn ul_posz CHAR 1\n-----------------\n")
    data = header.encode() + b"abc" * 20
    p = tmp_path / "x_bndl.json"
    p.write_text(json.dumps({"ssffFiles": [{"fileExtension": "ul",
                                            "data": base64.b64encode(data).decode()}]}))
    with pytest.raises(DataError, match=r"x_bndl\.json: track 'ul': position column 'ul_posx' holds "
                                        r"\|S1 \(CHAR\), not numbers"):
        load_trial(p)
    p.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(DataError, match=r"x_bndl\.json: JSON nested too deeply"):
        load_trial(p)


def test_a_lateral_jaw_sensor_taken_for_the_midline_one_is_named_with_the_fix(tmp_path: Path) -> None:
    """Issue 25 item 3: a lateral jaw sensor (Haskins' JAWL) given as JAW got a warning recommending
    the axes already in use. The German EMA with a lateral jaw sensor added (the midline jw moved 15 mm
    along x, the lateral axis) and taken as JAW: the warning names the lateral sensor and the midline
    one to give instead; the axes are not blamed. With jw as JAW, no warning."""
    import warnings

    from coartic.io.errors import DataWarning

    src = REAL / "dfgspp_mo1_prosody_0020_ema.csv"
    lines = src.read_text().splitlines()
    header = lines[0].split(",")
    cols = [header.index(f"jw_{c}") for c in ("posx", "posy", "posz", "orix", "oriy", "oriz")]
    out = [lines[0] + "," + ",".join(f"jwl_{c}" for c in ("posx", "posy", "posz", "orix", "oriy", "oriz"))]
    for line in lines[1:]:
        cells = line.split(",")
        extra = [cells[k] for k in cols]
        if extra[0]:
            extra[0] = repr(float(extra[0]) + 15.0)  # 15 mm to the side
        out.append(line + "," + ",".join(extra))
    p = tmp_path / "lateral_jaw.csv"
    p.write_text("\n".join(out) + "\n")
    axes = {"vertical": "+z", "anterior": "-y"}
    with pytest.warns(DataWarning) as caught:
        load_trial(p, role_map={"UL": "ul", "LL": "ll", "JAW": "jwl", "axes": axes}).channels()
    said = " ".join(str(w.message) for w in caught)
    assert "the sensor taken as JAW ('jwl') is 1" in said and "lateral jaw sensor" in said
    assert 'e.g. {"JAW": "jw"}' in said and "axes look wrong" not in said
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        load_trial(p, role_map={"UL": "ul", "LL": "ll", "JAW": "jw", "axes": axes}).channels()
