"""The Italian table shipped inside the package (python/coartic/runtime/italian_table.json): it
loads, covers every phoneme of the model's Italian phone set on every lip, jaw and tongue channel,
is what `make table-italian` (or `make table-italian-changed`) wrote (its recorded checksums; no
refit here), and `coartic speak` / `animate` use it when --table is omitted, saying so; its tongue
is the default tongue of a table without one."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.io.labelmap import MODEL_CONSONANTS, MODEL_VOWELS
from coartic.runtime.shipped import (
    SHIPPED_PROVENANCE,
    SHIPPED_TABLE,
    load_shipped_table,
    shipped_provenance,
    shipped_table_path,
)
from coartic.table import CHANNELS, PAUSE, TONGUE_CHANNELS, ParameterTable

ROOT = Path(__file__).resolve().parents[2]
# the whole model phone set: the vowels, the consonants and /j w/ (Festival's Italian voice writes them)
ITALIAN = (PAUSE, *MODEL_VOWELS, *MODEL_CONSONANTS)
PARAGRAPH = ("Ieri sera siamo andati al cinema con gli amici di Giorgio. Il film era lungo ma molto bello: "
             "parlava di un vecchio pescatore che viveva sulla costa, vicino a Genova. Dopo siamo tornati "
             "a casa a piedi, perché la notte era chiara e faceva ancora caldo.")


def test_shipped_table_is_package_data_that_loads_and_covers_the_phone_set() -> None:
    path = shipped_table_path()
    assert path.parent == ROOT / "python" / "coartic" / "runtime"  # maturin's python-source ships it
    table = load_shipped_table()
    assert table.variant == "modified" and tuple(table.channels) == CHANNELS + TONGUE_CHANNELS
    assert sorted(table.phonemes) == sorted(ITALIAN)
    for ph in ITALIAN:
        for ch in table.channels:
            v = table.values[ph][ch]
            assert all(np.isfinite(x) for x in v.values()), (ph, ch)
    # the fit kept what makes the face right: closures and lip-teeth contact always reached
    for ph in ("p", "b", "m"):
        assert table.values[ph]["ULO"]["k_r"] > 0.9 and table.values[ph]["LLO"]["k_r"] > 0.9
    for ph in ("f", "v"):
        assert table.values[ph]["LLO"]["k_r"] > 0.9 and table.values[ph]["LLP"]["k_r"] > 0.9
    # ... rounding the face shows from the front, and the tongue's contacts
    assert table.values["u"]["LR"]["target"] <= 0.8 * table.values[PAUSE]["LR"]["target"]
    for ph, ch in (("t", "TTH"), ("d", "TTH"), ("n", "TTH"), ("k", "TBH"), ("g", "TBH")):
        assert table.values[ph][ch]["k_r"] > 0.9 and table.values[ph][ch]["target"] > 8.0, (ph, ch)


def test_shipped_table_is_what_make_table_italian_wrote_from_the_current_inputs() -> None:
    prov = shipped_provenance()
    assert prov["command"] in ("make table-italian", "make table-italian-changed") and prov["table"] == SHIPPED_TABLE
    assert hashlib.sha256(shipped_table_path().read_bytes()).hexdigest() == prov["table_sha256"], (
        "the shipped table was edited by hand: run `make table-italian`")
    for rel, digest in prov["inputs_sha256"].items():
        assert hashlib.sha256((ROOT / rel).read_bytes()).hexdigest() == digest, (
            f"{rel} changed since the shipped table was fitted: run `make table-italian` and commit its output")
    assert set(prov["inputs_sha256"]) == {"corpus-synthetic/ground_truth_italian.json", "corpus-synthetic/session.toml",
                                          "fit/italian.toml", "fit/italian_tongue.toml"}
    assert sorted(prov["phonemes"]) == sorted(ITALIAN) and prov["channels"] == [*CHANNELS, *TONGUE_CHANNELS]
    # every channel was fitted now or kept, and a kept channel says from which table and why
    refit = prov["refit"]
    assert sorted(refit["fitted_now"] + refit["kept"]) == sorted(prov["channels"])
    assert set(TONGUE_CHANNELS) <= set(refit["fitted_now"])
    if refit["kept"]:
        assert prov["command"] == "make table-italian-changed"
        assert sorted(refit["changed_channels"]["changed"]) == sorted(set(CHANNELS) - set(refit["kept"]))
        assert refit["changed_channels"]["trials"] == 1932 and "bit for bit" in refit["why"]
    # the recovery bar was met on every channel, and the held-out error is measured beside its baselines
    assert prov["recovery_check"][-1] == "bar met"
    assert [line.split()[0] for line in prov["recovery_check"][1:-1]] == prov["channels"]
    for split, per in prov["held_out_rmse_mm"].items():
        for ch in prov["channels"]:
            fitted, floor = per["fitted_table"][ch], per["ground_truth"][ch]
            before = per["class_default_tongue" if ch in TONGUE_CHANNELS else "three_vowel_table_with_fallbacks"][ch]
            assert fitted < 0.3 and fitted < before, (split, ch)
            assert fitted >= floor - 0.01, (split, ch)  # no table beats the truth by more than chance


def test_shipped_table_is_close_to_the_ground_truth_it_was_fitted_on() -> None:
    shipped = load_shipped_table()
    truth = ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth_italian.json")
    worst = max(abs(shipped.values[p][ch]["target"] - truth.values[p][ch]["target"])
                for p in ITALIAN for ch in truth.channels)
    assert worst < 0.2


def test_animate_without_table_uses_the_shipped_one_and_says_so(tmp_path: Path) -> None:
    labels = tmp_path / "vieni.tsv"
    rows = [(0.0, 0.3, "#"), (0.3, 0.38, "v"), (0.38, 0.45, "i"), (0.45, 0.6, "E"), (0.6, 0.68, "n"),
            (0.68, 0.8, "i"), (0.8, 1.1, "#")]
    labels.write_text("".join(f"{s}\t{e}\t{p}\n" for s, e, p in rows))
    res = CliRunner().invoke(app, ["animate", str(labels), "-o", str(tmp_path / "o"), "--preview", "none"])
    assert res.exit_code == 0, res.output
    said = " ".join(res.output.split())
    assert f"{SHIPPED_TABLE} (shipped with coartic" in said and "the table has no" not in said
    shown = [ln.split("\t")[3] for ln in (tmp_path / "o" / "segments.tsv").read_text().splitlines()[1:]]
    # "vieni" stays "vieni": no fallback (the runtime may close the utterance with a pause of its own)
    assert [p for p in shown if p != PAUSE] == [p for _, _, p in rows if p != PAUSE] and shown[0] == PAUSE
    # with --table the shipped table is not mentioned
    res = CliRunner().invoke(app, ["animate", str(labels), "-t", str(shipped_table_path()), "-o",
                                   str(tmp_path / "p"), "--preview", "none"])
    assert res.exit_code == 0 and "shipped with coartic" not in res.output


@pytest.mark.festival
def test_italian_paragraph_needs_no_fallback(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["speak", PARAGRAPH, "-o", str(tmp_path / "o"), "--preview", "none",
                                   "--fap-name", "paragrafo", "--strict"])
    assert res.exit_code == 0, res.output
    said = " ".join(res.output.split())
    assert "shipped with coartic" in said and "the table has no" not in said
    segs = [ln.split("\t") for ln in (tmp_path / "o" / "segments.tsv").read_text().splitlines()[1:]]
    vowels = [s for s in segs if s[2] in MODEL_VOWELS]
    assert {s[2] for s in vowels} == set(MODEL_VOWELS)  # the paragraph has all seven vowels
    assert all(s[2] == s[3] for s in segs)  # every phoneme shown as itself


def test_provenance_file_is_json_beside_the_table() -> None:
    path = shipped_table_path().with_name(SHIPPED_PROVENANCE)
    assert json.loads(path.read_text(encoding="utf-8")) == shipped_provenance()


def test_a_table_without_tongue_takes_the_shipped_tongue(tmp_path: Path) -> None:
    """The tongue FAPs of a lip-only table come from the shipped table's tongue channels (through the
    model, on the animation's segments); a table with tongue channels uses its own."""
    from coartic.io.labels import read_labels
    from coartic.runtime.animate import animate, target_times
    from coartic.runtime.tongue import tongue_channels

    (tmp_path / "u.tsv").write_text("start\tend\tlabel\n0\t0.3\t#\n0.3\t0.46\ta\n0.46\t0.56\tt\n0.56\t0.72\ta\n"
                                    "0.72\t0.82\tk\n0.82\t0.98\ta\n0.98\t1.3\t#\n")
    segs = read_labels(tmp_path / "u.tsv")
    shipped = load_shipped_table()
    lips = ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth.json")
    an = animate(lips, segs, 100.0)
    got, rest, own = tongue_channels(an)
    want = animate(shipped, an.segments, 100.0, duration=an.duration, channels=list(TONGUE_CHANNELS)).channels
    assert own == [] and rest == {ch: shipped.values[PAUSE][ch]["target"] for ch in TONGUE_CHANNELS}
    for ch in TONGUE_CHANNELS:
        np.testing.assert_allclose(got[ch], want[ch][: len(got[ch])])
    k = {ph: int(round(t * 100)) for ph, t in zip(segs.labels, target_times(shipped, segs, "TTH"))}
    assert got["TTH"][k["t"]] > 7.0 and got["TBH"][k["k"]] > 9.0 and got["TTH"][k["a"]] < -5.0
    _, _, own = tongue_channels(animate(shipped, segs, 100.0))
    assert own == list(TONGUE_CHANNELS)
    # an utterance without the tongue channels' reference phoneme /a/ (alpha = 1) is animated too
    (tmp_path / "iti.tsv").write_text("start\tend\tlabel\n0\t0.3\t#\n0.3\t0.46\ti\n0.46\t0.56\tt\n0.56\t0.72\ti\n"
                                      "0.72\t1.0\t#\n")
    iti = animate(lips, read_labels(tmp_path / "iti.tsv"), 100.0)
    got, _, _ = tongue_channels(iti)
    assert got["TTH"].max() > 7.0


def test_the_shipped_tongue_is_made_once_and_again_when_the_file_changes(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Every animation's FAPs take the shipped tongue (``shipped_tongue_table``): one table per set of
    phonemes, shared, not the shipped file loaded and validated each time; a shipped file rewritten
    meanwhile (`make table-italian` beside a running session) is read again."""
    import os

    import coartic.runtime.shipped as shipped
    import coartic.runtime.tongue as tongue

    copy = tmp_path / SHIPPED_TABLE
    copy.write_bytes(shipped_table_path().read_bytes())
    monkeypatch.setattr(shipped, "shipped_table_path", lambda: copy)  # what load_shipped_table reads
    monkeypatch.setattr(tongue, "shipped_table_path", lambda: copy)
    first = tongue.shipped_tongue_table([PAUSE, "a", "t"])
    assert tongue.shipped_tongue_table([PAUSE, "a", "t"]) is first
    assert first.values["t"]["TTH"]["target"] == pytest.approx(9.0, abs=0.01)
    doc = json.loads(copy.read_text(encoding="utf-8"))
    doc["phonemes"]["t"]["TTH"]["target"] = 7.5
    copy.write_text(json.dumps(doc), encoding="utf-8")
    st = copy.stat()
    os.utime(copy, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a later time whatever the clock's grain
    again = tongue.shipped_tongue_table([PAUSE, "a", "t"])
    assert again is not first and again.values["t"]["TTH"]["target"] == 7.5
