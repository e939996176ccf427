"""The end of an utterance: the mouth is not widest after the voice has stopped (issue 20, item 7).

The final pause's target lies in its middle, so a long trailing silence aimed the return to rest
late; `split_final_pause` gives the model a final pause of FINAL_PAUSE_S and holds the rest."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coartic.io.labels import Segments
from coartic.runtime.animate import FINAL_PAUSE_S, evaluate, split_final_pause
from coartic.runtime.pipeline import animate_file
from coartic.table import PAUSE, ParameterTable

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
# the end of Festival's "Il babbo mangia la pappa." (pc_diphone): /p p a/ then 0.43 s of silence
LABELS = [("#", 0.0, 0.30), ("a", 0.30, 0.40), ("p", 0.40, 0.450), ("p", 0.450, 0.517), ("a", 0.517, 0.576),
          ("#", 0.576, 1.003)]


def _segments() -> Segments:
    return Segments(tuple(p for p, _, _ in LABELS), np.array([s for _, s, _ in LABELS]),
                    np.array([e for _, _, e in LABELS]))


def _widest_after_voice(seg: Segments, table: ParameterTable) -> float:
    t = np.arange(0.517, seg.ends[-1], 0.001)
    ch = evaluate(table, seg, t, ["ULO", "LLO"])
    return float(t[int(np.argmax(ch["ULO"] + ch["LLO"]))] - 0.576)


def test_final_pause_split() -> None:
    seg = _segments()
    split, origin = split_final_pause(seg)
    assert split.labels == (*seg.labels, PAUSE)
    assert origin == [0, 1, 2, 3, 4, 5, 5]
    assert split.ends[-2] == seg.starts[-1] + FINAL_PAUSE_S and split.ends[-1] == seg.ends[-1]
    assert split.starts[-1] == split.ends[-2]
    # a short final pause, no final pause, or only silence: unchanged
    short = Segments(seg.labels, seg.starts, np.append(seg.ends[:-1], 0.576 + FINAL_PAUSE_S))
    assert split_final_pause(short)[0] is short
    assert split_final_pause(Segments(seg.labels[:-1], seg.starts[:-1], seg.ends[:-1]))[0].labels == seg.labels[:-1]
    silent = Segments((PAUSE,), np.array([0.0]), np.array([2.0]))
    assert split_final_pause(silent)[0] is silent


def test_mouth_not_widest_after_the_voice_stops() -> None:
    table = ParameterTable.load(GROUND_TRUTH)
    seg = _segments()
    assert _widest_after_voice(seg, table) > 0.02  # as labelled: 40-odd ms into the silence
    assert _widest_after_voice(split_final_pause(seg)[0], table) <= 0.0


def test_animate_writes_the_split_and_animates_it_again(tmp_path: Path) -> None:
    labels = tmp_path / "pappa.tsv"
    labels.write_text("".join(f"{s} {e} {p}\n" for p, s, e in LABELS))
    table = ParameterTable.load(GROUND_TRUTH)
    out = animate_file(labels, table, tmp_path / "o", preview="none")
    rows = (tmp_path / "o" / "segments.tsv").read_text().splitlines()[1:]
    assert [r.split("\t")[2] for r in rows] == ["#", "a", "p", "p", "a", "#", "#"]
    assert out.animation.n_frames == round(1.003 * 25)
    again = animate_file(tmp_path / "o" / "segments.tsv", table, tmp_path / "o2", preview="none")
    for c in out.animation.channels:
        np.testing.assert_array_equal(again.animation.channels[c], out.animation.channels[c])
