"""Small recordings written in the exact formats the corpora are distributed in (MOCHA-TIMIT EST
tracks, binary and ASCII; X-ray Microbeam .txy; mview MATLAB .mat; Carstens AG501 .pos; EMA CSV
with lab sensor names), with label files in each corpus' phone set, so the readers are tested on
the bytes a user has.

One utterance, /# p a m i t u #/, whose articulators follow the synthetic session's ground-truth
model (corpus-synthetic/ground_truth.json) for the lips and jaw, and made-up but smooth tongue
motion; every format stores the same motion in its own axes and units. Run as a script to write
the files into a folder: `python tests/python/format_fixtures.py OUT`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[2]
TRUTH = ROOT / "corpus-synthetic" / "ground_truth.json"

PHONEMES = ("#", "p", "a", "m", "i", "t", "u", "#")
DURATIONS = (0.20, 0.08, 0.16, 0.08, 0.16, 0.07, 0.18, 0.20)
# the same phones in each corpus' own labels
MOCHA_LABELS = ("sil", "p", "aa", "m", "ii", "t", "uu", "sil")  # MRPA, as MOCHA-TIMIT's .lab
ARPABET_LABELS = ("sil", "P", "AA1", "M", "IY1", "T", "UW1", "sil")  # MFA english_us_arpa
TIMIT_LABELS = ("h#", "p", "aa", "m", "iy", "t", "uw", "h#")  # TIMIT, as XRMB alignments

# rest positions (mm) in a head frame with a = anterior, v = vertical
REST = {"UL": (10.0, 0.0), "LL": (9.0, -16.0), "JAW": (-2.0, -24.0), "TT": (-12.0, -6.0),
        "TB": (-35.0, 2.0), "TD": (-50.0, 0.0), "UI": (0.0, -8.0)}


@dataclass(frozen=True)
class Motion:
    times: NDArray[np.float64]
    # sensor → (anterior, vertical) in mm, frames x 2
    sensors: dict[str, NDArray[np.float64]]
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]


def segments() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    ends = np.cumsum(DURATIONS)
    return np.concatenate([[0.0], ends[:-1]]), ends


def motion(rate: float) -> Motion:
    """The articulators at `rate` Hz over the utterance (the last frame before its end)."""
    from coartic import ParameterTable, trajectories

    starts, ends = segments()
    n = int(np.floor(ends[-1] * rate + 1e-6))
    times = np.arange(n) / rate
    table = ParameterTable.load(TRUTH)
    ch = trajectories(table, list(PHONEMES), starts, ends, times, channels=["ULO", "LLO", "JO", "ULP"])
    rest = {c: float(ch[c][0]) for c in ch}
    lo, up = ch["LLO"] - rest["LLO"], ch["ULO"] - rest["ULO"]
    jaw = ch["JO"] - rest["JO"]
    prot = ch["ULP"] - rest["ULP"]
    # the tongue: the tip rises for /t/, the body fronts for /i/ and backs for /u/ (smooth bumps)
    def bump(centre: float, width: float) -> NDArray[np.float64]:
        return np.exp(-0.5 * ((times - centre) / width) ** 2)

    mid = 0.5 * (starts + ends)
    tip_up = 8.0 * bump(mid[5], 0.05) - 0.4 * jaw
    body_fwd = 6.0 * bump(mid[4], 0.07) - 5.0 * bump(mid[6], 0.07)
    body_up = 4.0 * bump(mid[4], 0.07) + 3.0 * bump(mid[6], 0.07) - 0.5 * jaw
    s = {
        "UL": np.stack([REST["UL"][0] + prot, REST["UL"][1] + up], axis=1),
        "LL": np.stack([REST["LL"][0] + prot, REST["LL"][1] - lo], axis=1),
        "JAW": np.stack([REST["JAW"][0] - 0.2 * jaw, REST["JAW"][1] - jaw], axis=1),
        "TT": np.stack([REST["TT"][0] + 0.3 * body_fwd, REST["TT"][1] + tip_up], axis=1),
        "TB": np.stack([REST["TB"][0] + body_fwd, REST["TB"][1] + body_up], axis=1),
        "TD": np.stack([REST["TD"][0] + 0.7 * body_fwd, REST["TD"][1] + 0.8 * body_up], axis=1),
        "UI": np.stack([np.full(n, REST["UI"][0]), np.full(n, REST["UI"][1])], axis=1),
    }
    return Motion(times, s, starts, ends)


# ------------------------------------------------------------------ MOCHA-TIMIT EST tracks

MOCHA_SENSORS = {"ui": "UI", "li": "JAW", "ul": "UL", "ll": "LL", "tt": "TT", "tb": "TB", "td": "TD",
                 "v": None, "bn": None, "bt": None}
# MOCHA's channel order (its headers list x of five sensors, then their y, then the others)
MOCHA_CHANNELS = ("ui_x", "li_x", "ul_x", "ll_x", "tt_x", "ui_y", "li_y", "ul_y", "ll_y", "tt_y",
                  "tb_x", "td_x", "v_x ", "****", "tb_y", "td_y", "v_y", "****", "bn_x", "bn_y")


def mocha_columns(m: Motion) -> NDArray[np.float64]:
    """frames x 20 in MOCHA's units (1/100 mm): x grows towards the back, y up."""
    cols = []
    for name in MOCHA_CHANNELS:
        name = name.strip()
        if name == "****":
            cols.append(np.zeros(m.times.size))
            continue
        sensor, axis = name.split("_")
        role = MOCHA_SENSORS[sensor]
        if role is None:  # velum, bridge of the nose: still
            base = {"v": (-60.0, 5.0), "bn": (20.0, 40.0), "bt": (0.0, 0.0)}[sensor]
            value = np.full(m.times.size, -base[0] if axis == "x" else base[1])
        else:
            a, v = m.sensors[role][:, 0], m.sensors[role][:, 1]
            value = -a if axis == "x" else v
        cols.append(100.0 * value)
    return np.stack(cols, axis=1)


def write_mocha_est(path: Path, m: Motion, binary: bool = True, byte_order: str = "01",
                    breaks: tuple[int, ...] = ()) -> Path:
    data = mocha_columns(m)
    flags = np.ones(m.times.size)
    flags[list(breaks)] = 0.0
    head = ["EST_File Track", f"DataType {'binary' if binary else 'ascii'}",
            f"NumFrames {m.times.size}"]
    if binary:
        head.append(f"ByteOrder {byte_order}")
    head += [f"NumChannels {data.shape[1]}", "EqualSpace 1", "BreaksPresent true",
             "CommentChar ;", ""]
    head += [f"Channel_{i} {c}" for i, c in enumerate(MOCHA_CHANNELS)]
    head.append("EST_Header_End")
    frames = np.column_stack([m.times, flags, data])
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii"))
        if binary:
            f.write(frames.astype("<f4" if byte_order == "01" else ">f4").tobytes())
        else:
            for row in frames:
                f.write((" ".join(f"{v:.4f}" for v in row) + "\n").encode("ascii"))
    return path


MNGU0_SENSORS = {"T1": "TT", "T2": None, "T3": "TB", "jaw": "JAW", "upperlip": "UL",
                 "lowerlip": "LL"}


def write_mngu0_est(path: Path, m: Motion) -> Path:
    """An mngu0-style EST track: `<sensor>_px/_py/_pz` in mm (x backwards, y lateral, z up) and
    the angles `_ph`, `_pt`, big-endian binary."""
    names, cols = [], []
    for sensor, role in MNGU0_SENSORS.items():
        a, v = m.sensors[role].T if role is not None else (np.full(m.times.size, -25.0),
                                                          np.full(m.times.size, -2.0))
        for suffix, value in (("px", -a), ("py", 0.2 + 0 * a), ("pz", v), ("ph", 0 * a), ("pt", 0 * a)):
            names.append(f"{sensor}_{suffix}")
            cols.append(value)
    frames = np.column_stack([m.times, np.ones(m.times.size), *cols])
    head = ["EST_File Track", "DataType binary", "ByteOrder 10", f"NumFrames {m.times.size}",
            f"NumChannels {len(names)}", "NumAuxChannels 0", "EqualSpace 1", "BreaksPresent true"]
    head += [f"Channel_{i} {c}" for i, c in enumerate(names)] + ["EST_Header_End"]
    path.write_bytes(("\n".join(head) + "\n").encode("ascii") + frames.astype(">f4").tobytes())
    return path


def write_mocha_lab(path: Path, m: Motion) -> Path:
    """MOCHA-TIMIT .lab: `start end label` in seconds."""
    path.write_text("".join(f"{s:.4f} {e:.4f} {lab}\n"
                            for s, e, lab in zip(m.starts, m.ends, MOCHA_LABELS)))
    return path


# ------------------------------------------------------------------ X-ray Microbeam .txy

XRMB_PELLETS = {"UL": "UL", "LL": "LL", "T1": "TT", "T2": None, "T3": "TB", "T4": "TD",
                "MI": "JAW", "MM": None}
XRMB_STEP_US = 6868  # 145.6 Hz


def write_txy(path: Path, m: Motion, lost: dict[str, tuple[int, ...]] | None = None) -> Path:
    """x anterior, y up, micrometres; time in microseconds; 1000000 where a pellet is lost."""
    lost = lost or {}
    lines = []
    for k in range(m.times.size):
        fields = [str(int(round(m.times[k] * 1e6)))]
        for pellet, role in XRMB_PELLETS.items():
            if k in lost.get(pellet, ()):
                fields += ["1000000", "1000000"]
                continue
            if role is None:
                a, v = (-25.0, -2.0) if pellet == "T2" else (-40.0, -30.0)
                if pellet == "MM":
                    a, v = m.sensors["JAW"][k, 0] - 40.0, m.sensors["JAW"][k, 1] + 5.0
            else:
                a, v = m.sensors[role][k]
            fields += [str(int(round(a * 1000))), str(int(round(v * 1000)))]
        lines.append(" ".join(fields))
    path.write_text("\n".join(lines) + "\n")
    return path


def xrmb_motion() -> Motion:
    return motion(1e6 / XRMB_STEP_US)


# ------------------------------------------------------------------ mview .mat (Haskins)

MVIEW_SENSORS = ("TR", "TB", "TT", "UL", "LL", "JAW")


def label_structs(starts: NDArray[np.float64], ends: NDArray[np.float64],
                  labels: tuple[str, ...]) -> NDArray[np.void]:
    """A 1 x n struct array of LABEL and OFFS ([start end], s), as the Haskins files' PHONES."""
    dtype = [("LABEL", object), ("OFFS", object)]
    return np.array([(lab, np.array([[float(s), float(e)]])) for s, e, lab in zip(starts, ends, labels)],
                    dtype=dtype).reshape(1, -1)


def write_mview(path: Path, m: Motion, planar: bool = False, swap_ll_jaw: bool = False,
                audio_rate: float = 22050.0, phones: tuple[str, ...] | None = None) -> Path:
    """A struct array named after the file: AUDIO first, then the sensors (x forwards, y lateral,
    z up; mm; columns x y z and three of orientation), or x and z only when `planar`. With
    `phones`, the Haskins IEEE database's fields too: the audio element carries the sentence and
    its alignment (WORDS, PHONES: LABEL and OFFS), the sensors carry them empty."""
    import scipy.io

    rate = 1.0 / (m.times[1] - m.times[0])
    dtype = [("NAME", object), ("SRATE", object), ("SIGNAL", object), ("SOURCE", object)]
    audio = ("AUDIO", audio_rate, np.zeros((int(m.times.size * audio_rate / rate), 1)), "synthetic")
    if phones is not None:
        dtype += [("SENTENCE", object), ("WORDS", object), ("PHONES", object), ("LABELS", object)]
        words = label_structs(m.starts[1:2], m.ends[-2:-1], ("PAMITU",))
        audio += ("Pa mi tu.", words, label_structs(m.starts, m.ends, phones), np.zeros((0, 0)))
    rows = [audio]
    for name in MVIEW_SENSORS:
        role = {"TR": "TD", "JAW": "JAW"}.get(name, name)
        if swap_ll_jaw and name in ("LL", "JAW"):
            role = "JAW" if name == "LL" else "LL"
        a, v = m.sensors[role][:, 0], m.sensors[role][:, 1]
        if planar:
            sig = np.stack([a, v], axis=1)
        else:
            lateral = 0.3 * np.sin(7 * m.times)
            sig = np.column_stack([a, lateral, v, np.zeros((m.times.size, 3))])
        empty = (np.zeros((0, 0)),) * 4 if phones is not None else ()
        rows.append((name, rate, sig, "synthetic") + empty)
    arr = np.array(rows, dtype=dtype).reshape(1, -1)
    scipy.io.savemat(path, {path.stem: arr})
    return path


# ------------------------------------------------------------------ EMA CSV, lab names

def write_lab_csv(path: Path, m: Motion, names: dict[str, str] | None = None,
                  planar: bool = False) -> Path:
    """`time_s, <S>_x, <S>_y, <S>_z` with sensors named as EMA labs name them (UL LL JAW TT TB
    TD), default EMA axes (up = +z, forwards = -y); midsagittal: `<S>_y, <S>_z` only."""
    names = names or {"UL": "UL", "LL": "LL", "JAW": "JAW", "TT": "TT", "TB": "TB", "TD": "TD"}
    axes = "yz" if planar else "xyz"
    header = ["time_s"] + [f"{n}_{a}" for n in names.values() for a in axes]
    out = [",".join(header)]
    for k, t in enumerate(m.times):
        row = [repr(float(t))]
        for role in names:
            a, v = m.sensors[role][k]
            xyz = {"x": 0.1, "y": -a, "z": v}
            row += [repr(float(xyz[ax])) for ax in axes]
        out.append(",".join(row))
    path.write_text("\n".join(out) + "\n")
    return path


# ------------------------------------------------------------------ Carstens AG50x .pos

CARSTENS_CHANNELS = {3: "UL", 4: "LL", 5: "JAW", 6: "TT", 7: "TB", 8: "TD"}  # channel → role


def write_carstens_pos(path: Path, m: Motion, header: bool = True, channels: int = 16,
                       sensor_file: bool = True) -> Path:
    """An AG501 file (V002 header; AG500: none) as Carstens documents it: little-endian float32,
    per frame every channel's x y z phi theta rms extra. Axes as a head-corrected session often
    has them: x backwards, y lateral, z up, mm. Channels not in CARSTENS_CHANNELS are unplugged
    (all zero); with `sensor_file`, `<stem>.sensors` names the plugged ones."""
    frames = np.zeros((m.times.size, channels, 7), dtype="<f4")
    for ch, role in CARSTENS_CHANNELS.items():
        a, v = m.sensors[role][:, 0], m.sensors[role][:, 1]
        frames[:, ch - 1, 0] = -a
        frames[:, ch - 1, 1] = 0.5  # the midline, as the lateral axis sees it
        frames[:, ch - 1, 2] = v
        frames[:, ch - 1, 3:5] = (10.0, 80.0)
        frames[:, ch - 1, 5] = 0.4
    head = b""
    if header:
        rate = 1.0 / (m.times[1] - m.times[0])
        lines = (f"NumberOfChannels={channels}\nSamplingFrequencyHz={rate:g}\n").encode()
        size = len(b"AG50xDATA_V002\n") + 9 + len(lines) + 2
        head = b"AG50xDATA_V002\n" + f"{size:08d}\n".encode() + lines + b"\x00\x1a"
    path.write_bytes(head + frames.tobytes())
    if sensor_file:
        path.with_suffix(".sensors").write_text(
            "# channel  sensor\n" + "".join(f"{ch} {role}\n" for ch, role in CARSTENS_CHANNELS.items()))
    return path


def write_mfa_textgrid(path: Path, m: Motion, labels: tuple[str, ...] = ARPABET_LABELS) -> Path:
    """A Montreal-Forced-Aligner TextGrid: the words tier first, then the phones tier."""
    xmax = float(m.ends[-1])
    words = [(0.0, float(m.starts[1]), ""), (float(m.starts[1]), float(m.ends[-2]), "pamitu"),
             (float(m.ends[-2]), xmax, "")]
    phones = [(float(s), float(e), "" if lab == "sil" else lab)
              for s, e, lab in zip(m.starts, m.ends, labels)]
    return write_textgrid(path, [("words", words), ("phones", phones)])


def write_tsv_labels(path: Path, m: Motion, labels: tuple[str, ...]) -> Path:
    path.write_text("".join(f"{float(s)!r}\t{float(e)!r}\t{lab}\n"
                            for s, e, lab in zip(m.starts, m.ends, labels)))
    return path


def write_all(out: Path) -> dict[str, tuple[Path, Path, str]]:
    """Every format: name → (data file, label file, label map)."""
    out.mkdir(parents=True, exist_ok=True)
    mocha = motion(500.0)
    xrmb = xrmb_motion()
    hask = motion(100.0)
    ema = motion(200.0)
    ag501 = motion(250.0)
    return {
        "mocha-binary": (write_mocha_est(out / "fsew0_001.ema", mocha),
                         write_mocha_lab(out / "fsew0_001.lab", mocha), "mocha"),
        "mocha-ascii": (write_mocha_est(out / "msak0_001.ema", mocha, binary=False),
                        write_mocha_lab(out / "msak0_001.lab", mocha), "mocha"),
        "xrmb": (write_txy(out / "tp001.txy", xrmb, lost={"T4": (3, 4, 5)}),
                 write_mfa_textgrid(out / "tp001.TextGrid", xrmb, TIMIT_LABELS), "timit"),
        "mview": (write_mview(out / "F01_B01_S01_R01_N.mat", hask),
                  write_tsv_labels(out / "F01_B01_S01_R01_N.tsv", hask, ARPABET_LABELS),
                  "english_arpabet"),
        "carstens": (write_carstens_pos(out / "0001.pos", ag501),
                     write_mfa_textgrid(out / "0001.TextGrid", ag501), "english_arpabet"),
        "lab-csv": (write_lab_csv(out / "utt_lab.csv", ema),
                    write_mfa_textgrid(out / "utt_lab.TextGrid", ema), "english_arpabet"),
    }


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/python/format_fixtures.py OUT")
    for name, (data, labels, lmap) in write_all(Path(sys.argv[1])).items():
        print(f"{name}: {data} {labels} (label map {lmap})")


def write_textgrid(path: Path, tiers: list[tuple[str, list[tuple[float, float, str]]]]) -> Path:
    """A long-format Praat TextGrid of interval tiers: (name, [(xmin, xmax, text), ...]) each."""
    xmax = max(e for _, items in tiers for _, e, _ in items)
    out = ['File type = "ooTextFile"', 'Object class = "TextGrid"', "", "xmin = 0", f"xmax = {xmax!r}",
           "tiers? <exists>", f"size = {len(tiers)}", "item []:"]
    for k, (name, items) in enumerate(tiers, start=1):
        out += [f"    item [{k}]:", '        class = "IntervalTier"', f'        name = "{name}"', "        xmin = 0",
                f"        xmax = {xmax!r}", f"        intervals: size = {len(items)}"]
        for j, (s, e, lab) in enumerate(items, start=1):
            out += [f"        intervals [{j}]:", f"            xmin = {s!r}", f"            xmax = {e!r}",
                    f'            text = "{lab}"']
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path
