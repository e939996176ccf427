"""ParameterTable: bit-for-bit JSON and CSV round trips, and a precise message for every error."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coartic.table import (
    ALL_CHANNELS,
    CHANNELS,
    DEFAULT_BOUNDS,
    N_PARAMS,
    PARAMETERS,
    QUANTILES,
    SCHEMA,
    ParameterTable,
    TableError,
)

ROW = {"target": 12.0, "alpha": 1.0, "theta_bw": 40.0, "theta_fw": 40.0, "c_bw": 1.0, "c_fw": 1.0,
       "k_r": 0.3, "sigma": 0.0, "psi": 100.0, "delta": 0.0}


def base_doc() -> dict[str, Any]:
    """The example of docs/ARCHITECTURE.md, plus a /p/."""
    return {
        "schema": SCHEMA,
        "variant": "modified",
        "channels": {"LLO": {"unit": "mm", "beta": 1.0, "edge_extent": 1.0, "apex_fraction": 0.5,
                             "reference_phoneme": "a"}},
        "phonemes": {"a": {"LLO": dict(ROW)}, "p": {"LLO": dict(ROW, target=-2.0, alpha=1.5, k_r=1.0)}},
        "bounds": {"LLO": {"target": [-5.0, 30.0]}},
        "uncertainty": {"a": {"LLO": {"target": {"q2.5": 11.8, "q16": 11.9, "q50": 12.0, "q84": 12.1,
                                                 "q97.5": 12.2}}}},
        "reasons": {"a": {"LLO": {"target": "open vowel: the largest lower-lip opening"}}},
        "metadata": {"method": "scipy-least-squares", "rmse": {"LLO": 0.21}},
    }


def test_names_follow_the_contract() -> None:
    assert CHANNELS == ("ULO", "LLO", "ULP", "LLP", "LR", "JO")
    assert ALL_CHANNELS == CHANNELS + ("LA", "TTH", "TTA", "TBH", "TBA")
    assert PARAMETERS[0] == "target" and PARAMETERS[6] == "k_r" and PARAMETERS[9] == "delta"
    assert N_PARAMS == 10 and set(DEFAULT_BOUNDS) == set(PARAMETERS)
    assert DEFAULT_BOUNDS["k_r"] == (0.0, 1.0) and DEFAULT_BOUNDS["c_bw"] == (0.5, 3.0)


def test_the_architecture_example_loads(tmp_path: Path) -> None:
    path = tmp_path / "table.json"
    path.write_text(json.dumps(base_doc()))
    t = ParameterTable.load(path)
    params, beta = t.to_matrix("LLO", ["p", "a"])
    assert params.shape == (2, 10) and params.dtype == np.float64 and beta == 1.0
    assert params[0, PARAMETERS.index("k_r")] == 1.0 and params[1, 0] == 12.0
    assert t.bounds_for("LLO", "target") == (-5.0, 30.0)
    assert t.bounds_for("LLO", "k_r") == (0.0, 1.0)
    assert t.phonemes_for("LLO") == ["a", "p"]


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


def rows(draw: st.DrawFn) -> dict[str, float]:
    return {
        "target": draw(st.floats(-1e6, 1e6)),
        "alpha": draw(st.floats(1e-300, 1e300, exclude_min=False)),
        "theta_bw": draw(st.floats(5e-324, 1e300).filter(lambda x: x > 0)),
        "theta_fw": draw(st.floats(1e-3, 1e4)),
        "c_bw": draw(st.floats(0.5, 3.0)),
        "c_fw": draw(st.floats(0.5, 3.0)),
        "k_r": draw(st.floats(0.0, 1.0)),
        "sigma": draw(st.floats(-0.5, 0.5)),
        "psi": draw(st.floats(1e-6, 1e6)),
        "delta": draw(st.floats(-0.08, 0.08)),
    }


@st.composite
def tables(draw: st.DrawFn) -> ParameterTable:
    channels = draw(st.lists(st.sampled_from(ALL_CHANNELS), min_size=1, max_size=3, unique=True))
    phonemes = draw(st.lists(st.sampled_from(["#", "a", "i", "u", "p", "tS", "J", "L", "ò"]), min_size=1,
                             max_size=5, unique=True))
    values = {ph: {ch: rows(draw) for ch in channels} for ph in phonemes}
    reference = {ch: draw(st.sampled_from(phonemes)) for ch in channels}
    for ch, ph in reference.items():
        values[ph][ch]["alpha"] = 1.0
    settings_ = {ch: {"beta": draw(st.floats(0.0, 10.0)), "edge_extent": draw(st.floats(1e-3, 5.0)),
                      "apex_fraction": draw(st.floats(0.0, 1.0)), "unit": draw(st.sampled_from(["mm", "cm"]))}
                 for ch in channels}
    t = ParameterTable.from_rows(values, reference, variant=draw(st.sampled_from(["original", "modified"])),
                                 settings=settings_)
    if draw(st.booleans()):
        ph, ch = phonemes[0], channels[0]
        qs = sorted(draw(st.lists(finite, min_size=5, max_size=5)))
        t.uncertainty = {ph: {ch: {"delta": dict(zip(QUANTILES, qs))}}}
    t.reasons = {phonemes[0]: {channels[0]: {"target": draw(st.text(max_size=30))}}}
    t.metadata = {"method": "hypothesis", "rmse": {channels[0]: draw(finite)}}
    t.validate()
    return t


@settings(max_examples=40, deadline=None)
@given(tables())
def test_json_round_trip_is_bit_for_bit(tmp_path_factory: pytest.TempPathFactory, table: ParameterTable) -> None:
    path = tmp_path_factory.mktemp("t") / "table.json"
    table.save(path)
    back = ParameterTable.load(path)
    assert back == table
    for ch in table.channels:
        a, beta_a = table.to_matrix(ch)
        b, beta_b = back.to_matrix(ch)
        assert a.tobytes() == b.tobytes() and math.copysign(1, beta_a) == math.copysign(1, beta_b)
    path2 = path.with_name("again.json")
    back.save(path2)
    assert path2.read_bytes() == path.read_bytes()


@settings(max_examples=40, deadline=None)
@given(tables())
def test_csv_round_trip_keeps_values_settings_and_uncertainty(tmp_path_factory: pytest.TempPathFactory,
                                                               table: ParameterTable) -> None:
    path = tmp_path_factory.mktemp("t") / "table.csv"
    table.save(path.with_suffix(".json"))  # the settings, beside the values (as every command writes them)
    table.save(path)
    back = ParameterTable.load(path)
    assert back.values == table.values and back.channels == table.channels
    assert back.variant == table.variant and back.uncertainty == table.uncertainty
    for ch in table.channels:
        assert table.to_matrix(ch)[0].tobytes() == back.to_matrix(ch)[0].tobytes()
    # a long CSV of earlier versions (settings in "*" rows) still reads alone, to the same table
    old = tmp_path_factory.mktemp("old") / "table.csv"
    old.write_text(long_csv(table))
    back = ParameterTable.load(old)
    assert back.values == table.values and back.channels == table.channels and back.uncertainty == table.uncertainty


def long_csv(table: ParameterTable) -> str:
    """The long CSV earlier versions wrote (a fixed format: written out here, not by the package)."""
    import csv
    import io

    from coartic.table import QUANTILES

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    with_q = bool(table.uncertainty)
    pad = [""] * len(QUANTILES) if with_q else []
    w.writerow(["phoneme", "channel", "parameter", "value"] + (list(QUANTILES) if with_q else []))
    w.writerow(["*", "*", "variant", table.variant] + pad)
    for ch, cs in table.channels.items():
        w.writerow(["*", ch, "unit", cs.unit] + pad)
        for name in ("beta", "edge_extent", "apex_fraction"):
            w.writerow(["*", ch, name, repr(float(getattr(cs, name)))] + pad)
        w.writerow(["*", ch, "reference_phoneme", cs.reference_phoneme] + pad)
        for name, v in cs.rate_settings().items():
            text = repr(float(v)) if name == "plateau_fraction" else str(v).lower() if name == "handover" else v
            w.writerow(["*", ch, name, text] + pad)
    for ph, chans in table.values.items():
        for ch, row in chans.items():
            for name in PARAMETERS:
                qs = table.uncertainty.get(ph, {}).get(ch, {}).get(name, {})
                w.writerow([ph, ch, name, repr(float(row[name]))] + ([repr(qs[q]) if q in qs else "" for q in QUANTILES]
                                                                     if with_q else []))
    return buf.getvalue()


@pytest.mark.full_env
def test_csv_is_tidy_and_pandas_reads_numbers(tmp_path: Path) -> None:
    pd = pytest.importorskip("pandas", reason="the [dataframe] extra (absent in make test-core)")

    t = ParameterTable.from_json_dict(base_doc())
    lines = t.to_csv().splitlines()
    assert lines[0] == "channel,phoneme,parameter,value,q2.5,q16,q50,q84,q97.5"
    assert "LLO,a,target,12.0,11.8,11.9,12.0,12.1,12.2" in lines
    assert "LLO,p,k_r,1.0,,,,," in lines
    assert len(lines) == 1 + sum(len(chans) for chans in t.values.values()) * len(PARAMETERS)  # values only
    t.save(tmp_path / "table.json")
    t.save(tmp_path / "table.csv")
    df = pd.read_csv(tmp_path / "table.csv")
    assert list(df.columns) == ["channel", "phoneme", "parameter", "value", "q2.5", "q16", "q50", "q84", "q97.5"]
    assert all(pd.api.types.is_float_dtype(df[c]) for c in df.columns[3:])
    pd.testing.assert_frame_equal(df, t.to_dataframe())  # the file and the DataFrame: same rows, same bits
    row = df[(df.phoneme == "a") & (df.parameter == "target")].iloc[0]
    assert row["value"] == 12.0 and row["q2.5"] == 11.8
    # the CSV alone cannot be evaluated: its settings are in the JSON, and it says so
    (tmp_path / "table.json").unlink()
    with pytest.raises(TableError, match=r"table\.csv: a table CSV holds the values only.*\.json"):
        ParameterTable.load(tmp_path / "table.csv")
    # an edited value is read from the CSV, its settings from the JSON beside it
    t.save(tmp_path / "table.json")
    (tmp_path / "table.csv").write_text(t.to_csv().replace("LLO,a,target,12.0,", "LLO,a,target,12.5,"))
    back = ParameterTable.load(tmp_path / "table.csv")
    assert back.values["a"]["LLO"]["target"] == 12.5 and back.channels == t.channels
    (tmp_path / "table.csv").write_text(t.to_csv().replace("LLO,a,target,12.0,", "JO,a,target,12.0,"))
    with pytest.raises(TableError, match=r"line \d+: phoneme 'a', channel 'JO': channel 'JO' is not in"):
        ParameterTable.load(tmp_path / "table.csv")


def test_set_from_matrix_round_trip_and_rollback() -> None:
    t = ParameterTable.from_json_dict(base_doc())
    params, beta = t.to_matrix("LLO", ["a", "p"])
    params[1, 0] = -3.5
    t.set_from_matrix("LLO", ["a", "p"], params, beta=2.0)
    assert t.values["p"]["LLO"]["target"] == -3.5 and t.channels["LLO"].beta == 2.0
    params[1, 6] = 1.3
    with pytest.raises(TableError, match=r"phoneme 'p', channel 'LLO': k_r = 1.3 is outside \[0, 1\]"):
        t.set_from_matrix("LLO", ["a", "p"], params, beta=5.0)
    assert t.values["p"]["LLO"]["k_r"] == 1.0 and t.channels["LLO"].beta == 2.0
    with pytest.raises(TableError, match=r"params has shape \(2, 9\), expected \(2, 10\)"):
        t.set_from_matrix("LLO", ["a", "p"], params[:, :9])
    with pytest.raises(TableError, match=r"phoneme 'a' appears twice"):
        t.set_from_matrix("LLO", ["a", "a"], params)
    with pytest.raises(TableError, match=r"settings of channel 'LLO': unknown key 'speed'"):
        ParameterTable.from_rows({"a": {"LLO": ROW}}, {"LLO": "a"}, settings={"LLO": {"speed": 1.0}})


def mutate(path: list[Any], value: Any) -> dict[str, Any]:
    doc = copy.deepcopy(base_doc())
    node = doc
    for key in path[:-1]:
        node = node[key]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


DELETE = object()
ERRORS = [
    (["schema"], "coartic.table/2", r"schema is 'coartic.table/2', this version of coartic reads 'coartic.table/1'"),
    (["variant"], "new", r"variant 'new' is not one of original, modified"),
    (["channels", "LLO", "reference_phoneme"], "o", r"channel 'LLO': reference phoneme 'o' has no parameters for LLO"),
    (["channels", "LLO", "beta"], -1.0, r"channel 'LLO': beta = -1.0 is outside \[0, inf\)"),
    (["channels", "LLO", "apex_fraction"], 2.0, r"apex_fraction = 2.0 is outside \[0, 1\]"),
    (["channels", "LLO", "speed"], 2.0, r"channel 'LLO': unknown key 'speed'"),
    (["channels", "XYZ"], {"reference_phoneme": "a"}, r"unknown channel 'XYZ'"),
    (["phonemes", "p", "LLO", "k_r"], 1.3, r"phoneme 'p', channel 'LLO': k_r = 1.3 is outside \[0, 1\]"),
    (["phonemes", "p", "LLO", "alpha"], 0.0, r"phoneme 'p', channel 'LLO': alpha = 0.0 is outside \(0, inf\)"),
    (["phonemes", "p", "LLO", "c_fw"], 0.2, r"c_fw = 0.2 is outside \[0.5, 3\]"),
    (["phonemes", "p", "LLO", "target"], 31.0, r"phoneme 'p', channel 'LLO': target = 31.0 is outside \[-5, 30\]"),
    (["phonemes", "p", "LLO", "sigma"], "0.1", r"sigma = '0.1' is not a number"),
    (["phonemes", "p", "LLO", "sigma"], True, r"sigma = True is not a number"),
    (["phonemes", "p", "LLO", "psi"], DELETE, r"phoneme 'p', channel 'LLO': missing parameter\(s\) psi"),
    (["phonemes", "p", "LLO", "gamma"], 1.0, r"unknown parameter 'gamma'"),
    (["phonemes", "p", "ULO"], dict(ROW), r"phoneme 'p', channel 'ULO': the channel is not declared"),
    (["phonemes", "a", "LLO", "alpha"], 2.0, r"alpha = 2.0, but 'a' is the reference phoneme of LLO"),
    (["bounds", "LLO", "target"], [30.0, -5.0], r"bounds for channel 'LLO', target: \[30.0, -5.0\] is not an interval"),
    (["bounds", "LLO", "target"], [1.0], r"expected \[lo, hi\]"),
    (["uncertainty", "a", "LLO", "target", "q99"], 1.0, r"unknown quantile 'q99'"),
    (["uncertainty", "a", "LLO", "target", "q16"], 13.0, r"quantiles are not in increasing order"),
    (["uncertainty", "o"], {"LLO": {"target": {"q50": 1.0}}}, r"uncertainty of phoneme 'o'.*no such parameter"),
    (["reasons", "a", "LLO", "target"], 3, r"reason for phoneme 'a'.*must name a parameter and be a string"),
    (["extra"], 1, r"unknown top-level key 'extra'"),
    (["phonemes"], DELETE, r"missing required key 'phonemes'"),
    (["metadata"], [1], r"metadata: expected a JSON object, got list"),
]


@pytest.mark.parametrize(("path", "value", "pattern"), ERRORS, ids=[m for _, _, m in ERRORS])
def test_every_error_names_file_and_entry(tmp_path: Path, path: list[Any], value: Any, pattern: str) -> None:
    file = tmp_path / "table.json"
    file.write_text(json.dumps(mutate(path, value)))
    with pytest.raises(TableError, match=rf"^{file}: .*{pattern}"):
        ParameterTable.load(file)


def test_nan_and_bad_json_and_bad_csv(tmp_path: Path) -> None:
    file = tmp_path / "table.json"
    doc = base_doc()
    doc["phonemes"]["a"]["LLO"]["delta"] = math.nan  # json writes the non-standard NaN
    file.write_text(json.dumps(doc))
    with pytest.raises(TableError, match=r"phoneme 'a', channel 'LLO': delta = nan is not finite"):
        ParameterTable.load(file)
    file.write_text('{"schema": "coartic.table/1",\n "variant": }')
    with pytest.raises(TableError, match=rf"{file}: line 2, column 13: invalid JSON"):
        ParameterTable.load(file)
    with pytest.raises(TableError, match=r"cannot read the table"):
        ParameterTable.load(tmp_path / "missing.json")
    csv_file = tmp_path / "t.csv"
    ParameterTable.from_json_dict(base_doc()).save(tmp_path / "t.json")
    text = ParameterTable.from_json_dict(base_doc()).to_csv()
    csv_file.write_text(text.replace("LLO,p,theta_fw,40.0", "LLO,p,theta_fw,fast"))
    with pytest.raises(TableError, match=r"t.csv: line \d+: phoneme 'p', channel 'LLO': theta_fw = 'fast' is not a number"):
        ParameterTable.load(csv_file)
    csv_file.write_text("phoneme;channel\n")
    with pytest.raises(TableError, match=r"line 1: header must be"):
        ParameterTable.load(csv_file)


def test_programmatic_ints_are_numbers_and_bad_metadata_is_named(tmp_path: Path) -> None:
    t = ParameterTable.from_json_dict(base_doc())
    t.bounds = {"LLO": {"target": (-5, 30)}}
    t.uncertainty = {"a": {"LLO": {"k_r": {"q16": 0, "q84": 1}}}}
    t.validate()
    t.metadata = {"rmse": {"LLO": math.nan}}
    with pytest.raises(TableError, match=r"t.json: metadata cannot be written as JSON"):
        t.save(tmp_path / "t.json")


def test_to_matrix_errors() -> None:
    t = ParameterTable.from_json_dict(base_doc())
    with pytest.raises(TableError, match=r"channel 'JO' is not in the table \(channels: LLO\)"):
        t.to_matrix("JO")
    with pytest.raises(TableError, match=r"phoneme 'u' has no parameters for channel 'LLO' \(phonemes with LLO: a, p\)"):
        t.to_matrix("LLO", ["a", "u"])


def test_strict_loading_duplicates_encoding_depth_and_huge_numbers(tmp_path: Path) -> None:
    p = tmp_path / "t.json"
    text = json.dumps(base_doc(), indent=2)
    # a second "variant" key: json keeps the last one silently
    p.write_text(text.replace('"variant": "modified",', '"variant": "modified",\n  "variant": "original",'))
    with pytest.raises(TableError, match=r"t\.json: line 4: key 'variant' appears twice in one object"):
        ParameterTable.load(p)
    p.write_text(text.replace('"alpha": 1.0,', '"alpha": 1.0, "alpha": 2.0,', 1))
    with pytest.raises(TableError, match=r"t\.json: key 'alpha' appears twice in one object"):
        ParameterTable.load(p)
    p.write_bytes(text.replace('"variant"', '"var\xe9iant"').encode("latin-1"))
    with pytest.raises(TableError, match=r"t\.json: line 3, column 7: byte 0xe9 is not UTF-8; this table must be UTF-8 text, and "
                       r"it decodes as cp1252"):
        ParameterTable.load(p)
    p.write_text('{"metadata": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(TableError, match=r"t\.json: JSON nested 100001 levels deep"):
        ParameterTable.load(p)
    p.write_text(text.replace('"beta": 1.0', '"beta": ' + "1" * 5000))
    with pytest.raises(TableError, match=r"t\.json: a number cannot be read: .*4300 digits"):
        ParameterTable.load(p)
    p.write_text(text.replace('"beta": 1.0', '"beta": ' + "1" * 400))
    with pytest.raises(TableError, match=r"beta = 1111.*\(400 digits\) is not a finite number"):
        ParameterTable.load(p)
    c = tmp_path / "t.csv"
    table = ParameterTable.from_json_dict(base_doc())
    table.save(tmp_path / "t.json")
    lines = table.to_csv().splitlines()
    row = next(ln for ln in lines if ",target," in ln)
    c.write_text("\n".join([*lines, row.replace(row.split(",")[3], "99.0")]) + "\n")
    with pytest.raises(TableError, match=rf"t\.csv: line {len(lines) + 1}: .*target is given twice \(first "
                                         rf"on line {lines.index(row) + 1}\)"):
        ParameterTable.load(c)


def test_bounds_wider_than_the_model_cannot_let_a_value_outside_its_domain_through(tmp_path: Path) -> None:
    # issue 21: such a table used to load, and the core's refusal was then blamed on the label file
    doc = base_doc()
    doc["bounds"]["LLO"]["k_r"] = [0.0, 2.0]
    doc["phonemes"]["p"]["LLO"]["k_r"] = 1.5
    file = tmp_path / "table.json"
    file.write_text(json.dumps(doc))
    with pytest.raises(TableError, match=rf"^{file}: phoneme 'p', channel 'LLO': k_r = 1.5 is outside \[0, 1\], "
                                         r"the model's domain of k_r \(MODEL.md §1\), whatever the table's bounds say"):
        ParameterTable.load(file)
    doc["bounds"]["LLO"]["c_bw"] = [0.1, 5.0]  # wider than the default box, inside the model's domain: fine
    doc["phonemes"]["p"]["LLO"].update(k_r=1.0, c_bw=4.0)
    file.write_text(json.dumps(doc))
    assert ParameterTable.load(file).values["p"]["LLO"]["c_bw"] == 4.0


@pytest.mark.parametrize("name", PARAMETERS)
def test_the_model_domain_is_the_one_the_core_checks(name: str) -> None:
    """MODEL_DOMAIN (Python: specs and tables) and validate_params (Rust) refuse the same values."""
    from coartic import _core
    from coartic.table import MODEL_DOMAIN, domain_problem

    corpus = _core.Corpus(np.array([0, 2]), np.array([0, 1]), np.array([0.0, 0.1]), np.array([0.1, 0.2]),
                          np.array([0, 3]), np.array([0.05, 0.1, 0.15]), 2)
    lo, hi, _ = MODEL_DOMAIN[name]
    probes = [v for b in (lo, hi) if math.isfinite(b) for v in (b - 1e-9, b, b + 1e-9)] + [1e300, -1e300]
    for v in probes:
        params = np.array([[ROW[p] for p in PARAMETERS]] * 2, dtype=np.float64)
        params[1, PARAMETERS.index(name)] = v
        try:
            _core.evaluate(corpus, params, 1.0, _core.ModelOptions("modified"))
            core_accepts = True
        except ValueError:
            core_accepts = False
        assert core_accepts == (domain_problem(name, v) is None), (name, v)


@pytest.mark.parametrize("name", ["beta", "edge_extent", "apex_fraction", "plateau_fraction"])
def test_the_channel_settings_ranges_are_the_ones_the_core_checks(name: str) -> None:
    """coartic.settings (specs, tables, [choose]) and the core's ModelOptions / β check agree."""
    from coartic import _core
    from coartic.settings import CHANNEL_SETTINGS

    setting = CHANNEL_SETTINGS[name]
    corpus = _core.Corpus(np.array([0, 1]), np.array([0]), np.array([0.0]), np.array([0.1]),
                          np.array([0, 1]), np.array([0.05]), 1)
    params = np.array([[ROW[p] for p in PARAMETERS]], dtype=np.float64)
    probes = [v for b in (setting.low, setting.high) if math.isfinite(b) for v in (b - 1e-9, b, b + 1e-9)]
    for v in probes + [math.nan, math.inf]:
        kwargs: dict[str, Any] = {"dominance": "plateau"} if name == "plateau_fraction" else {}
        try:
            if name == "beta":
                _core.evaluate(corpus, params, v, _core.ModelOptions("modified"))
            elif name == "plateau_fraction":
                _core.evaluate(corpus, params, 1.0, _core.ModelOptions("modified", plateau_fraction=v, **kwargs))
            else:
                _core.evaluate(corpus, params, 1.0, _core.ModelOptions("modified", **{name: v}))
            core_accepts = True
        except ValueError:
            core_accepts = False
        assert core_accepts == (setting.problem(v) is None), (name, v)


def test_the_core_defaults_are_the_channel_settings_defaults() -> None:
    """The one place a default is written twice: Rust's ModelOptions signature (the core cannot
    read Python). Its defaults are checked equal to coartic.settings'."""
    import inspect

    from coartic import _core
    from coartic.settings import CHANNEL_SETTINGS

    sig = inspect.signature(_core.ModelOptions).parameters
    in_core = [n for n in CHANNEL_SETTINGS if n in sig]
    assert in_core == ["edge_extent", "apex_fraction", "dominance", "plateau_fraction", "handover"]
    for name in in_core:
        assert sig[name].default == CHANNEL_SETTINGS[name].default, name
        assert getattr(_core.ModelOptions(), name) == CHANNEL_SETTINGS[name].default, name
