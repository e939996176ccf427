"""The Italian table shipped inside the package (python/coartic/runtime/italian_table.json): it
loads, covers every phoneme of the model's Italian phone set on every lip and jaw channel, is what
`make table-italian` wrote (its recorded checksums; no refit here), and `coartic speak` / `animate`
use it when --table is omitted, saying so."""

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
from coartic.table import CHANNELS, PAUSE, ParameterTable

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
    assert table.variant == "modified" and tuple(table.channels) == CHANNELS
    assert sorted(table.phonemes) == sorted(ITALIAN)
    for ph in ITALIAN:
        for ch in CHANNELS:
            v = table.values[ph][ch]
            assert all(np.isfinite(x) for x in v.values()), (ph, ch)
    # the fit kept what makes the face right: closures and lip-teeth contact always reached
    for ph in ("p", "b", "m"):
        assert table.values[ph]["ULO"]["k_r"] > 0.9 and table.values[ph]["LLO"]["k_r"] > 0.9
    for ph in ("f", "v"):
        assert table.values[ph]["LLO"]["k_r"] > 0.9 and table.values[ph]["LLP"]["k_r"] > 0.9


def test_shipped_table_is_what_make_table_italian_wrote_from_the_current_inputs() -> None:
    prov = shipped_provenance()
    assert prov["command"] == "make table-italian" and prov["table"] == SHIPPED_TABLE
    assert hashlib.sha256(shipped_table_path().read_bytes()).hexdigest() == prov["table_sha256"], (
        "the shipped table was edited by hand: run `make table-italian`")
    for rel, digest in prov["inputs_sha256"].items():
        assert hashlib.sha256((ROOT / rel).read_bytes()).hexdigest() == digest, (
            f"{rel} changed since the shipped table was fitted: run `make table-italian` and commit its output")
    assert set(prov["inputs_sha256"]) == {"corpus-synthetic/ground_truth_italian.json",
                                          "corpus-synthetic/session.toml", "fit/italian.toml"}
    assert sorted(prov["phonemes"]) == sorted(ITALIAN)
    # the recovery bar was met, and the held-out error is measured beside its baselines
    assert prov["recovery_check"][-1] == "bar met"
    for split, per in prov["held_out_rmse_mm"].items():
        for ch in CHANNELS:
            fitted, floor = per["fitted_table"][ch], per["ground_truth"][ch]
            assert fitted < 0.3 and fitted < per["three_vowel_table_with_fallbacks"][ch], (split, ch)
            assert fitted >= floor - 0.01, (split, ch)  # no table beats the truth by more than chance


def test_shipped_table_is_close_to_the_ground_truth_it_was_fitted_on() -> None:
    shipped = load_shipped_table()
    truth = ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth_italian.json")
    worst = max(abs(shipped.values[p][ch]["target"] - truth.values[p][ch]["target"])
                for p in ITALIAN for ch in CHANNELS)
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
