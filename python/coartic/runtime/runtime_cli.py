"""`coartic animate` and `coartic speak`: tables to moving lips, from label files or Italian/English text.

Without --table both use the table shipped in the package (coartic.runtime.shipped), and say so."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Callable

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from coartic.runtime.errors import AnimationError
from coartic.runtime.festival import LANGUAGES, start_synthesis
from coartic.runtime import PREVIEW_FORMATS
from coartic.console import LineProgress, positive_finite

# NumPy, the table, the model and the outputs are imported in the commands, after `speak` has
# started Festival: the imports then run while it synthesises (bench/startup.py).
if TYPE_CHECKING:
    from coartic.runtime.exporters import RigOptions
    from coartic.runtime.pipeline import RuntimeOutput
    from coartic.table import ParameterTable

_err = Console(stderr=True)
_out = Console()

TableOpt = Annotated[Path | None, typer.Option("--table", "-t", help="Parameter table (JSON or long CSV). Default: the Italian table shipped with coartic (every Italian phoneme, fitted on the synthetic session).")]
OutOpt = Annotated[Path, typer.Option("--out", "-o", help="Output directory (created if needed).")]
def _finite_fps(fps: float) -> float:
    # before fps_warnings (int(inf) would raise) and before any work; the upper bound is the frame count's
    if not (math.isfinite(fps) and fps > 0):
        raise typer.BadParameter(f"{fps:g} is not a frame rate: give a finite number of frames per second above 0 "
                                 "(25 for FAP players)")
    return fps


FpsOpt = Annotated[float, typer.Option("--fps", callback=_finite_fps,
                                       help="Frames per second of the channels, FAP file and preview.")]
MnsOpt = Annotated[float | None, typer.Option("--mns", help="The speaker's neutral mouth-nose separation, mm (FAPU = MNS/1024). Default 30 mm.")]
MwOpt = Annotated[float | None, typer.Option("--mw", help="The speaker's neutral mouth width, mm (FAPU = MW/1024). Default: the table's rest LR.")]
SnapOpt = Annotated[bool, typer.Option("--snap-contacts/--no-snap-contacts", help="Show each k_R = 1 target (lip closure, lip-teeth contact) on its nearest frame.")]
StrictOpt = Annotated[bool, typer.Option("--strict", help="Refuse phonemes the table lacks instead of using the phone map's fallbacks (phones_italian.tsv, phones_english.tsv).")]
PreviewOpt = Annotated[str, typer.Option("--preview", help=f"Preview format: {', '.join(PREVIEW_FORMATS)}.")]
GltfOpt = Annotated[bool, typer.Option("--gltf", help="Also write NAME.glb: the face with morph targets per FAP and their animation (coartic view DIR plays it).")]
VrmlOpt = Annotated[bool, typer.Option("--vrml", help="Also write NAME.wrl: the face animated in VRML97 (interpolators, the sound as an AudioClip).")]
FapNameOpt = Annotated[str | None, typer.Option("--fap-name", help="Name of the FAP file and its header; the WAV and glTF get the same stem (Greta loads NAME.fap with NAME.wav).")]
ExportOpt = Annotated[str | None, typer.Option("--export", help="Also write the rigs' curves and cues, comma-separated: arkit (NAME.arkit.csv/.json, ARKit's 52 blendshapes), visemes (NAME.visemes.csv/.json, Meta's 15), rhubarb (NAME.rhubarb.tsv/.json and --rhubarb-formats, Rhubarb Lip Sync's mouth cues).")]
GltfMorphsOpt = Annotated[str, typer.Option("--gltf-morphs", help="The glTF's morph targets: fap (one per FAP), arkit (ARKit's 52 blendshape names, to retarget by name) or eight (at most 8 per mesh, all blended by three.js up to r132); arkit and eight imply --gltf.")]
EmotionOpt = Annotated[str | None, typer.Option("--emotion", help="Speak with this emotion of a table fitted with [model] emotions (joy, surprise, sadness, disgust, anger, fear; docs/EMOTIONS.md).")]
IntensityOpt = Annotated[float, typer.Option("--intensity", help="With --emotion: 0 = neutral, 1 = the emotion as fitted (up to 1.5).")]
EmotionSpansOpt = Annotated[Path | None, typer.Option("--emotion-spans", help="Emotions over time: a TSV of spans 'start end emotion \\[intensity]' (s), ramped in and out over 0.2 s (docs/EMOTIONS.md).")]
EmotionMarkupOpt = Annotated[Path | None, typer.Option("--emotion-markup", help="The text to say with its emotions as APML-like markup: <performative affect=\"joy\" intensity=\"0.6\">words</performative> inside one root element (docs/EMOTIONS.md); instead of TEXT.")]
ExtendedOpt = Annotated[str, typer.Option("--extended-shapes", help="Rhubarb's extended mouth shapes the cues may use: any of G H X (as Rhubarb's --extendedShapes; \"\" for the six basic shapes A-F).")]
RhubarbFormatsOpt = Annotated[str, typer.Option("--rhubarb-formats", help="Rhubarb's cue files to write with --export rhubarb: any of tsv, json, xml, dat (Moho / OpenToonz switch data, at --fps 24 to 100), comma-separated.")]
PrestonBlairOpt = Annotated[bool, typer.Option("--preston-blair", help="Preston Blair's shape names (MBP, etc, E, AI, O, U, FV, L, rest) in Rhubarb's DAT file, as Rhubarb's --datUsePrestonBlair.")]
VisemeNamesOpt = Annotated[str, typer.Option("--viseme-names", help="Names of the viseme curves (--export visemes): meta (Oculus: sil PP ... ou), rpm (Ready Player Me, VRChat: viseme_sil ... viseme_U) or vrm (VRM's five vowels aa ih ou ee oh).")]
RigGainOpt = Annotated[float, typer.Option("--rig-gain", help="Exaggeration of the rigs' curves (--export arkit, visemes): every mouth and jaw weight times this (1 = the model's), clipped to 0..1.")]
RigScaleOpt = Annotated[str | None, typer.Option("--rig-scale", help="Per-shape scale of the rigs' curves, e.g. jawOpen=0.8,mouthFunnel=1.2 (names of the set written).")]
RigSmoothOpt = Annotated[float, typer.Option("--rig-smooth", help="Smooth the rigs' curves over this many seconds (a Hann window, no delay); 0 = off.")]
RigHoldOpt = Annotated[float, typer.Option("--rig-hold", help="Hold every peak of the rigs' curves at least this many seconds; also Rhubarb's shortest cue when above its 0.07 s. 0 = off.")]
SpeakerOpt = Annotated[str | None, typer.Option("--speaker", help="Speak as this speaker of a table fitted with \\[model] speakers (its offset and scale, or its own targets).")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Replace --out even if it holds another run's output "
                                        "(the same labels or text replace their own output without it).")]


def _progress() -> Progress:
    return LineProgress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                        console=_err)


def fps_warnings(fps: float) -> list[str]:
    """What FAP players do with a rate other than 25 fps (said before the run, not refused)."""
    if fps != int(fps):
        return [f"--fps {fps:g} is not a whole number: Xface reads the FAP header's rate as an integer "
                f"({int(fps)}) and would drift out of sync with the sound"]
    if fps != 25:
        return [f"--fps {fps:g}: Greta plays FAP files at 25 fps whatever the header says, so it would play "
                f"this one {fps / 25:.3g}x as long as the sound"]
    return []


def _warn_fps(fps: float) -> None:
    for msg in fps_warnings(fps):
        _err.print(f"[yellow]warning:[/] {escape(msg)}", highlight=False)


def _report(result: RuntimeOutput, phone_map: str = "phones_italian.tsv") -> None:
    a = result.animation
    summary = Table(title=f"{a.n_frames} frames at {a.fps:g} fps = {a.duration:.3f} s", show_header=False)
    summary.add_column("what")
    summary.add_column("file")
    for what, path in result.files.items():
        summary.add_row(what, str(path))
    _out.print(summary)
    if a.at_rest:
        _err.print(f"[yellow]note:[/] the table has no channel(s) {', '.join(a.at_rest)}: held at rest "
                   "(the neutral face) in the FAP file and preview, left out of channels.csv", highlight=False,
                   soft_wrap=True)
    if a.substitutions:
        from coartic.runtime.animate import NEXT_PHONEME

        subs = ", ".join(f"/{k}/ (shown as " + ("the phoneme after it" if v == NEXT_PHONEME else f"/{v}/") + ")"
                         for k, v in a.substitutions.items())
        _err.print(f"[yellow]note:[/] the table has no {escape(subs)}: the fallbacks of {phone_map} "
                   "(--strict refuses instead)", highlight=False, soft_wrap=True)


def _load_table(path: Path | None) -> ParameterTable:
    from coartic.table import ParameterTable

    if path is not None:
        return ParameterTable.load(path)
    from coartic.runtime.shipped import load_shipped_table

    table = load_shipped_table()
    _err.print(f"[cyan]table:[/] {escape(str(table.source))} (shipped with coartic: every Italian phoneme, fitted "
               "on the synthetic session; --table to use another)", highlight=False, soft_wrap=True)
    return table


def _moved(result: RuntimeOutput, staging: Path, out: Path) -> RuntimeOutput:
    """The result with its file paths where they are after the staging directory was swapped in."""
    result.files = {k: out / p.relative_to(staging) if p.is_relative_to(staging) else p for k, p in result.files.items()}
    return result


def _run_staged(table: Path | None, out: Path, command: str, identity: dict[str, str], force: bool,
                protect: list[Path], make: Callable[[ParameterTable, Path, Progress], RuntimeOutput],
                phone_map: str = "phones_italian.tsv", emotion: str | None = None, intensity: float = 1.0,
                emotion_spans: Path | None = None, markup: Any = None) -> None:
    """Load the table, run ``make`` into the staging directory of ``out`` with a progress bar, and
    report what was written (where it is once swapped in). ``emotion`` at ``intensity``: the table's
    emotion blended in first, or ``emotion_spans`` over time (coartic.emotions), or ``markup``'s
    (coartic.runtime.markup.Markup: timed once the words are said)."""
    from coartic.emotions import EmotionError, emotion_table, read_emotion_spans, with_emotion_spans
    from coartic.outputs import OutputDir
    from coartic.runtime.markup import with_markup

    given = [o for o, v in (("--emotion", emotion), ("--emotion-spans", emotion_spans), ("--emotion-markup", markup))
             if v is not None]
    if len(given) > 1:
        raise EmotionError(f"{' and '.join(given)}: give one (a span file or a markup can hold a single emotion over "
                           "the whole utterance)")
    t = emotion_table(_load_table(table), emotion, intensity)
    if markup is not None:
        t = with_markup(t, markup)
        identity = identity | {"emotion_markup": markup.source}
    if emotion is not None:
        identity = identity | {"emotion": emotion, "intensity": repr(float(intensity))}
    if emotion_spans is not None:
        t = with_emotion_spans(t, read_emotion_spans(emotion_spans), str(emotion_spans))
        identity = identity | {"emotion_spans": str(emotion_spans.resolve())}
    with OutputDir(out, command, identity, force=force, protect=protect) as staging, _progress() as progress:
        result = make(t, staging, progress)
    _report(_moved(result, staging, out), phone_map)


def _rig_options(extended_shapes: str, rhubarb_formats: str, preston_blair: bool, viseme_names: str, gain: float,
                 scale: str | None, smooth: float, hold: float) -> RigOptions:
    """The rig options of the command line, checked before anything runs."""
    from coartic.runtime.exporters import RigOptions, parse_shape_scale
    from coartic.runtime.rhubarb import parse_extended_shapes, parse_rhubarb_formats

    return RigOptions(extended_shapes=parse_extended_shapes(extended_shapes),
                      rhubarb_formats=parse_rhubarb_formats(rhubarb_formats), preston_blair=preston_blair,
                      viseme_names=viseme_names, gain=gain, shape_scale=parse_shape_scale(scale), smooth=smooth,
                      hold=hold)


def animate_command(
    labels: Annotated[Path, typer.Argument(help="Label file: Praat TextGrid, HTK/Festival .lab or TSV 'start end label'; "
                                                "or a recording (WAV) with --text or --transcript, aligned first (coartic align).")],
    out: OutOpt,
    table: TableOpt = None,
    fps: FpsOpt = 25.0,
    tier: Annotated[str | None, typer.Option("--tier", help="TextGrid tier with the phones (default: the first interval tier).")] = None,
    label_map: Annotated[str | None, typer.Option("--label-map", help="Corpus labels → model phonemes: a built-in map name or a TSV/JSON file (default: the map the table was fitted with).")] = None,
    mns: MnsOpt = None,
    mw: MwOpt = None,
    preview: PreviewOpt = "gif",
    snap_contacts: SnapOpt = True,
    strict: StrictOpt = False,
    audio: Annotated[Path | None, typer.Option("--audio", help="The recording the labels describe (WAV): copied as NAME.wav, the sound of the MP4 and the glTF bundle; the animation lasts as long.")] = None,
    fap_name: FapNameOpt = None,
    gltf: GltfOpt = False,
    vrml: VrmlOpt = False,
    speaker: SpeakerOpt = None,
    emotion: EmotionOpt = None,
    intensity: IntensityOpt = 1.0,
    emotion_spans: EmotionSpansOpt = None,
    export: ExportOpt = None,
    gltf_morphs: GltfMorphsOpt = "fap",
    extended_shapes: ExtendedOpt = "GHX",
    rhubarb_formats: RhubarbFormatsOpt = "tsv,json",
    preston_blair: PrestonBlairOpt = False,
    viseme_names: VisemeNamesOpt = "meta",
    rig_gain: RigGainOpt = 1.0,
    rig_scale: RigScaleOpt = None,
    rig_smooth: RigSmoothOpt = 0.0,
    rig_hold: RigHoldOpt = 0.0,
    force: ForceOpt = False,
    text: Annotated[str | None, typer.Option("--text", help="With a recording: what it says (its transcript).")] = None,
    transcript: Annotated[Path | None, typer.Option("--transcript", help="With a recording: its transcript as a file (plain text, or a TextGrid with a words tier).")] = None,
    lang: Annotated[str, typer.Option("--lang", help="With a recording: its language (it, en, de, or any espeak-ng voice); also picks the phone map's fallbacks.")] = "it",
    engine: Annotated[str | None, typer.Option("--engine", help="With a recording: the aligner (sphinx, festival, espeak; coartic align --help).")] = None,
    max_duration: Annotated[float, typer.Option("--max-duration", callback=positive_finite, help="With a recording: refuse recordings longer than this (s).")] = 3600.0,
) -> None:
    """Animate a label file, or a recording and its transcript: channel trajectories (CSV), an MPEG-4 FAP file and a preview.

    A recording (WAV) is aligned to its transcript first (as `coartic align`; the TextGrid is written
    beside the animation). The files are written beside --out and swapped in together when all are
    done (docs/OUTPUTS.md)."""
    from coartic.align.aligner import is_wav
    from coartic.runtime.pipeline import animate_file, speaker_face

    _warn_fps(fps)
    rig = _rig_options(extended_shapes, rhubarb_formats, preston_blair, viseme_names, rig_gain, rig_scale,
                       rig_smooth, rig_hold)
    if is_wav(labels):
        _animate_recording(labels, out, table, fps, text, transcript, lang, engine, max_duration, audio, force,
                           dict(tier=tier, label_map=label_map, preview=preview, snap_contacts=snap_contacts,
                                strict=strict, gltf=gltf or gltf_morphs != "fap", vrml=vrml, speaker=speaker,
                                exports=export, gltf_morphs=gltf_morphs, rig=rig), fap_name, mns, mw, speaker,
                           emotion, intensity, emotion_spans)
        return
    if text is not None or transcript is not None:
        if not labels.exists():
            raise AnimationError(f"{labels}: no such file (the recording to align to --text or --transcript)")
        raise AnimationError(f"{labels}: --text and --transcript go with a recording (WAV), and this is not one")

    def make(t: ParameterTable, staging: Path, progress: Progress) -> RuntimeOutput:
        return animate_file(labels, t, staging, fps=fps, tier=tier, label_map=label_map,
                            face=speaker_face(t, mns, mw, speaker), preview=preview, snap_contacts=snap_contacts,
                            strict=strict, progress=progress, audio=audio, name=fap_name,
                            gltf=gltf or gltf_morphs != "fap", vrml=vrml, speaker=speaker, exports=export,
                            gltf_morphs=gltf_morphs, rig=rig)

    _run_staged(table, out, "animate", {"labels": str(labels.resolve())}, force,
                [labels, *([table] if table is not None else []), *([audio] if audio is not None else [])], make,
                emotion=emotion, intensity=intensity, emotion_spans=emotion_spans)


def _animate_recording(wav: Path, out: Path, table: Path | None, fps: float, text: str | None, transcript: Path | None,
                       lang: str, engine: str | None, max_duration: float, audio: Path | None, force: bool,
                       options: dict[str, Any], name: str | None, mns: float | None, mw: float | None,
                       speaker: str | None, emotion: str | None = None, intensity: float = 1.0,
                       emotion_spans: Path | None = None) -> None:
    """`coartic animate voice.wav --text ...`: align, then animate with the recording as the sound."""
    from coartic.align.align_cli import part_progress, shown_warnings, transcript_text
    from coartic.align.aligner import animate_recording
    from coartic.runtime.pipeline import speaker_face

    if audio is not None:
        raise AnimationError(f"{wav} is a recording: it is the sound already, leave out --audio {audio}")
    if options["tier"] is not None or options["label_map"] is not None:
        raise AnimationError(f"{wav} is a recording: --tier and --label-map are for label files (the aligner "
                             "gives the model's phonemes)")
    for key in ("tier", "label_map"):
        del options[key]
    words = transcript_text(text, transcript)
    fallbacks = "phones_english.tsv" if lang.split("-")[0] == "en" else "the aligner's phone map"

    def make(t: ParameterTable, staging: Path, progress: Progress) -> RuntimeOutput:
        return animate_recording(wav, words, t, staging, lang=lang, engine=engine, max_duration=max_duration,
                                 align_progress=part_progress(progress, "aligning"), name=name, fps=fps,
                                 face=speaker_face(t, mns, mw, speaker), progress=progress, **options)

    identity = {"recording": str(wav.resolve()), "text": words or "", "lang": lang}
    with shown_warnings():
        _run_staged(table, out, "animate", identity, force,
                    [wav, *([table] if table is not None else []), *([transcript] if transcript else [])], make,
                    fallbacks, emotion, intensity, emotion_spans)


def speak_command(
    out: OutOpt,
    text: Annotated[str | None, typer.Argument(help="Text to say, e.g. \"Il babbo mangia la pappa.\" (Italian; --lang en for English); or --emotion-markup FILE instead")] = None,
    table: TableOpt = None,
    fps: FpsOpt = 25.0,
    lang: Annotated[str, typer.Option("--lang", help=f"Language of the text: {', '.join(LANGUAGES)} (Festival's Italian or English voice; English phones are mapped onto the model's Italian phonemes by phones_english.tsv).")] = "it",
    stretch: Annotated[float, typer.Option("--stretch", help="Festival's Duration_Stretch: 1 = normal rate, 0.6 = fast.")] = 1.0,
    voice: Annotated[str | None, typer.Option("--voice", help="Festival voice (Italian: pc_diphone (default), lp_diphone; English: kal_diphone (default)).")] = None,
    strict: StrictOpt = False,
    mns: MnsOpt = None,
    mw: MwOpt = None,
    preview: PreviewOpt = "gif",
    snap_contacts: SnapOpt = True,
    fap_name: FapNameOpt = None,
    gltf: GltfOpt = False,
    vrml: VrmlOpt = False,
    speaker: SpeakerOpt = None,
    emotion: EmotionOpt = None,
    intensity: IntensityOpt = 1.0,
    emotion_spans: EmotionSpansOpt = None,
    emotion_markup: EmotionMarkupOpt = None,
    export: ExportOpt = None,
    gltf_morphs: GltfMorphsOpt = "fap",
    extended_shapes: ExtendedOpt = "GHX",
    rhubarb_formats: RhubarbFormatsOpt = "tsv,json",
    preston_blair: PrestonBlairOpt = False,
    viseme_names: VisemeNamesOpt = "meta",
    rig_gain: RigGainOpt = 1.0,
    rig_scale: RigScaleOpt = None,
    rig_smooth: RigSmoothOpt = 0.0,
    rig_hold: RigHoldOpt = 0.0,
    force: ForceOpt = False,
) -> None:
    """Say Italian (or English, --lang en) text with Festival: WAV, channel trajectories, FAP file and preview,
    all as long as the WAV.

    The files are written beside --out and swapped in together when all are done (docs/OUTPUTS.md)."""
    markup = None
    if emotion_markup is not None:
        from coartic.runtime.markup import read_markup

        if text is not None:
            raise AnimationError(f"TEXT {text!r} and --emotion-markup {emotion_markup}: give one (the markup holds "
                                 "the words to say)")
        markup = read_markup(emotion_markup)
        text = markup.text
    if text is None:
        raise AnimationError("no text to say: give TEXT, or --emotion-markup FILE")
    if lang not in LANGUAGES:
        raise AnimationError(f"--lang {lang!r} is not a language coartic can speak (known: {', '.join(LANGUAGES)})")
    _warn_fps(fps)
    # Festival first: it synthesises while NumPy, the model and the table load (stopped on any error)
    synthesis = start_synthesis(text, stretch=stretch, voice=voice, lang=lang)
    with synthesis:
        from coartic.runtime.pipeline import speak_text, speaker_face

        rig = _rig_options(extended_shapes, rhubarb_formats, preston_blair, viseme_names, rig_gain, rig_scale,
                       rig_smooth, rig_hold)

        def make(t: ParameterTable, staging: Path, progress: Progress) -> RuntimeOutput:
            return speak_text(text, t, staging, fps=fps, stretch=stretch, voice=voice, strict=strict,
                              face=speaker_face(t, mns, mw, speaker), preview=preview, snap_contacts=snap_contacts,
                              progress=progress, name=fap_name, gltf=gltf or gltf_morphs != "fap", vrml=vrml,
                              speaker=speaker, exports=export, gltf_morphs=gltf_morphs, lang=lang, rig=rig,
                              synthesis=synthesis)

        # the identity of an Italian run stays {"text": ...}: outputs written before --lang existed are its own
        identity = {"text": text} | ({"lang": lang} if lang != "it" else {})
        _run_staged(table, out, "speak", identity, force,
                    [*([table] if table is not None else []), *([emotion_markup] if emotion_markup else [])], make,
                    LANGUAGES[lang][1], emotion, intensity, emotion_spans, markup)
