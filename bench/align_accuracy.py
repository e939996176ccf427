"""How accurate `coartic align` is, and what it does to the lips (docs/ALIGN.md; issue 26 item 2).

1. **Boundaries on real German recordings**: the three German EMA recordings with audio we may use
   (tests/data/realdata/emu-ema-german: mo1's 0020 and 0024; tests/data/realdata/emu-tinydfg91: s1em's
   0666), aligned from their audio and a transcript written from their MAUS phones, against those
   MAUS labels: median and 90th percentile boundary error, % within 20 and 40 ms. No second
   labelling of these recordings exists, so the labels' own agreement cannot be given.
2. **Choices, made on synthetic speech, not on those recordings**: the DTW step pattern and the
   English aligner, on sentences said by espeak-ng (its phoneme events are the exact reference)
   and aligned by the other TTS (Festival) or by PocketSphinx. English (en-us voice) and Italian.
3. **Confidence**: the warp distance ratio of each German recording with its own transcript and
   with another sentence's (AlignWarning above MISMATCH_RATIO).
4. **End to end, the lips**: fit utterance 0024 (fit/ema_german_defaults_0024.toml: the default model, MAUS labels), then
   predict 0020's lip aperture (LA) and jaw opening (JO) from its MAUS labels and from its audio
   alone (aligned by coartic), each against the step model (phoneme means of 0024) on the same
   segments: RMSE as measured, offset removed and speaker-calibrated (coartic.evaluation.score).

Output in bench/results/align_accuracy.txt:

    nice .venv/bin/python bench/align_accuracy.py
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
import wave
from pathlib import Path

import numpy as np

from coartic.align.accuracy import BoundaryAccuracy, boundary_accuracy
from coartic.align.alignment import MISMATCH_RATIO, STEP_PATTERN, align_by_synthesis
from coartic.align.audio import read_recording
from coartic.align.errors import AlignWarning
from coartic.align.espeak import speak
from coartic.align.aligner import align_english
from coartic.align.sphinx import recognise_phones
from coartic.align.synthesis import ipa_map, ipa_phone
from coartic.io.labelmap import LabelMap
from coartic.io.labels import Segments, read_labels

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "align_accuracy.txt"
TINY = "emu-tinydfg91/tinyDfg91/0000_ses/dfg91_s1em_0666_bndl/dfg91_s1em_0666"
# (name, recording, MAUS labels, transcript written from the MAUS phones)
GERMAN = [
    ("mo1 0020", "emu-ema-german/derived/dfgspp_mo1_prosody_0020.wav",
     "emu-ema-german/derived/dfgspp_mo1_prosody_0020_Segment.tsv", "Sie arbeitete in einer Kneipe als Kellnerin."),
    ("mo1 0024", "emu-ema-german/derived/dfgspp_mo1_prosody_0024.wav",
     "emu-ema-german/derived/dfgspp_mo1_prosody_0024_Segment.tsv",
     "Morgen muss sie wieder Klausur noch Examen schreiben."),
    ("s1em 0666", f"{TINY}.wav", f"{TINY}.MAU", "Melanies Omi kallim mit ihr ein Lied."),
]
OTHER_GERMAN = "Der Hund bellt laut im Garten hinter dem Haus."
# Harvard sentences (IEEE 1969), and Italian sentences of the same kind
ENGLISH = ["The birch canoe slid on the smooth planks.", "Glue the sheet to the dark blue background.",
           "It's easy to tell the depth of a well.", "These days a chicken leg is a rare dish.",
           "Rice is often served in round bowls.", "The juice of lemons makes fine punch.",
           "The box was thrown beside the parked truck.", "The hogs were fed chopped corn and garbage.",
           "Four hours of steady work faced us.", "A large size in stockings is hard to sell."]
ITALIAN = ["Il babbo mangia la pappa con la mamma.", "La volpe salta sopra il cane pigro.",
           "Oggi piove molto sulla città vecchia.", "Mio zio compra sempre il pane fresco.",
           "Le mele rosse sono buone da mangiare.", "Il gatto dorme sotto la sedia blu.",
           "Domani partiamo presto per il mare.", "La pizza napoletana ha il bordo alto."]
PATTERNS = ("symmetric2", "symmetricP05", "symmetricP1", "asymmetricP1")


def realdata_dir(given: str | None) -> Path:
    if given:
        return Path(given)
    return ROOT / "tests/data/realdata"  # both corpora are copied there, each with its licence


def espeak_reference(text: str, voice: str, wav: Path) -> Segments:
    """espeak-ng says `text` into `wav`; its phones (model phonemes) with their exact times."""
    said = speak(text, voice)
    with wave.open(str(wav), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(said.rate)
        w.writeframes((np.clip(said.samples, -1, 1) * 32767).astype("<i2").tobytes())
    pm = ipa_map()
    return Segments(tuple(pm.phonemes[ipa_phone(p)] if p else "#" for p in said.phones),
                    said.starts / said.rate, said.ends / said.rate)


def row(name: str, acc: BoundaryAccuracy, extra: str = "") -> str:
    return (f"{name:34s}{len(acc.errors):6d}{acc.median_ms:9.0f}{acc.p90_ms:9.0f}{100 * acc.within(20):9.0f}"
            f"{100 * acc.within(40):9.0f}{extra}")


HEADER = f"{'':34s}{'bounds':>6s}{'median':>9s}{'p90':>9s}{'<=20ms%':>9s}{'<=40ms%':>9s}"


def synthetic_choices(lines: list[str], ratios: list[str]) -> None:
    lines += ["## 2. choices on synthetic speech (espeak-ng's phone times as the reference)", HEADER]
    with tempfile.TemporaryDirectory() as tmp:
        sets = {"en": [(t, espeak_reference(t, "en-us", Path(tmp) / f"en{k}.wav"), Path(tmp) / f"en{k}.wav")
                       for k, t in enumerate(ENGLISH)],
                "it": [(t, espeak_reference(t, "it", Path(tmp) / f"it{k}.wav"), Path(tmp) / f"it{k}.wav")
                       for k, t in enumerate(ITALIAN)]}
        for lang, items in sets.items():
            for pattern in PATTERNS:
                accs = [boundary_accuracy(ref, align_by_synthesis(read_recording(wav), t, lang, "festival",
                                                                  step_pattern=pattern).segments())
                        for t, ref, wav in items]
                mark = "  <- default" if pattern == STEP_PATTERN else ""
                lines.append(row(f"{lang} Festival+DTW {pattern}", BoundaryAccuracy.pooled(accs), mark))
        items = sets["en"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AlignWarning)
            found = [(ref, align_english(read_recording(wav), t)) for t, ref, wav in items]
        fell_back = sum(not a.method.startswith("forced alignment") for _, a in found)
        accs = [boundary_accuracy(ref, a.segments()) for ref, a in found]
        lines.append(row("en PocketSphinx alignment", BoundaryAccuracy.pooled(accs),
                         f"  <- default for en ({fell_back} of {len(found)} fell back to Festival+DTW)"))
        accs = [boundary_accuracy(ref, a.segments()) for ref, a in found if a.method.startswith("forced alignment")]
        lines.append(row("  of which PocketSphinx itself", BoundaryAccuracy.pooled(accs)))
        wrong = [align_by_synthesis(read_recording(wav), items[(k + 1) % len(items)][0], "en", "festival").confidence
                 for k, (_, _, wav) in enumerate(items)]
        right = [a.confidence for _, a in found]
        ratios.append(f"English (espeak-ng en-us, Festival+DTW): own transcript {min(right):.3f}-{max(right):.3f}, "
                      f"the next sentence's {min(wrong):.3f}-{max(wrong):.3f}")
        accs = [boundary_accuracy(ref, recognise_phones(read_recording(wav)).segments()) for _, ref, wav in items]
        lines.append(row("en PocketSphinx, no transcript", BoundaryAccuracy.pooled(accs)))
    lines.append("")


def german_boundaries(data: Path, lines: list[str], ratios: list[str]) -> dict[str, Segments]:
    lines += ["## 1. boundaries against MAUS, real German recordings (espeak-ng + DTW, the default for de)", HEADER]
    lm = LabelMap.builtin("german_sampa")
    aligned: dict[str, Segments] = {}
    accs = []
    for name, wav, labels, text in GERMAN:
        if not (data / wav).exists():
            lines.append(f"{name}: {data / wav} not found (--realdata)")
            continue
        rec = read_recording(data / wav)
        reference = lm.apply(read_labels(data / labels))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AlignWarning)
            own = align_by_synthesis(rec, text, "de")
            other = align_by_synthesis(rec, OTHER_GERMAN, "de")
        acc = boundary_accuracy(reference, own.segments())
        accs.append(acc)
        aligned[name] = own.segments()
        lines.append(row(name, acc))
        ratios.append(f"{name}: own transcript {own.confidence:.3f}, another sentence {other.confidence:.3f}")
    lines += [row("pooled", BoundaryAccuracy.pooled(accs)), ""]
    return aligned


def lips(data: Path, aligned: dict[str, Segments], lines: list[str]) -> None:
    from coartic.fit import load_spec, run
    from coartic.fit.data import load_utterances
    from coartic.evaluation.score import score_utterances, with_fallbacks
    from coartic.model import Utterance

    lines += ["## 4. end to end: fit 0024 (fit/ema_german_defaults_0024.toml, MAUS labels), predict 0020's lips from its labels or its audio",
              "RMSE in mm on the same EMA samples; step = phoneme means of 0024 on the same segments", "",
              f"{'channel':8s}{'labels of 0020':16s}{'model':8s}{'as measured':>13s}{'offset removed':>16s}"
              f"{'calibrated':>12s}{'samples':>9s}"]
    spec = load_spec(ROOT / "fit" / "ema_german_defaults_0024.toml")
    res = run(spec, quiet=True)
    table = res.table()
    both = load_utterances(load_spec(ROOT / "fit" / "ema_german.toml"))
    by_id = {u.name.rsplit("_", 2)[-2]: u for u in both}
    test, train = by_id["0020"], by_id["0024"]
    seg = aligned["mo1 0020"]
    from_audio = Utterance(seg.labels, seg.starts, seg.ends, test.times, test.name + " (aligned)", test.observed,
                           test.valid, test.meta)
    lm = LabelMap.builtin("german_sampa")

    def scored_rows(pairs: list[tuple[str, Utterance]]) -> None:
        for what, utt in pairs:
            scored, note = with_fallbacks([utt], table, spec.channels, lm)
            sc = score_utterances(table, scored, spec.channels, train=[train])
            for r in sc.baseline_rows():
                if r["model"] in ("table", "step"):
                    lines.append(f"{r['channel']:8s}{what:16s}{r['model']:8s}{r['rmse_mm']:13.3f}"
                                 f"{r['rmse_offset_removed_mm']:16.3f}{r['rmse_calibrated_mm']:12.3f}{r['samples']:9d}")
            if note:
                lines.append(f"  note ({what}): {note}")
        lines.append("")

    scored_rows([("MAUS", test), ("coartic align", from_audio)])
    # another speaker and sentence: s1em's 0666 (the emuDB bundle, read through its _annot.json)
    if (data / f"{TINY}_annot.json").exists() and "s1em 0666" in aligned:
        lines += ["new speaker, new sentence: s1em 0666 predicted by the same table (mo1's); the calibrated column "
                  "fits a + b x prediction to the speaker", ""]
        with tempfile.TemporaryDirectory() as tmp:
            tiny_spec = Path(tmp) / "tiny.toml"
            tiny_spec.write_text(f'[corpus]\nfiles = ["{data / TINY}_annot.json"]\nlabels = ["{data / TINY}.MAU"]\n'
                                 'label_map = "german_sampa"\n[model]\nchannels = ["LA", "JO"]\n')
            (other,) = load_utterances(load_spec(tiny_spec))
        seg = aligned["s1em 0666"]
        heard = Utterance(seg.labels, seg.starts, seg.ends, other.times, other.name + " (aligned)", other.observed,
                          other.valid, other.meta)
        scored_rows([("MAUS", other), ("coartic align", heard)])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realdata", help="the realdata directory (default: tests/data/realdata)")
    parser.add_argument("--no-fit", action="store_true", help="leave out part 4 (it fits a table, ~2 min)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    data = realdata_dir(args.realdata)
    lines = ["# coartic align: accuracy and the lips (bench/align_accuracy.py)", f"realdata: {data.name}", ""]
    ratios: list[str] = []
    aligned = german_boundaries(data, lines, ratios)
    synthetic_choices(lines, ratios)
    lines += [f"## 3. confidence: warp distance ratio (warning above {MISMATCH_RATIO:g})", *ratios, ""]
    if not args.no_fit:
        lips(data, aligned, lines)
    lines.append(f"({time.perf_counter() - t0:.0f} s)")
    text = "\n".join(lines) + "\n"
    OUT.write_text(text, encoding="utf-8")
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
