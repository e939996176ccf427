"""Every output of `coartic animate` and `speak` is an exporter fed the same `FaceAnimation`.

An exporter is a function `(fed, settings) -> {what: path}`. The always-written ones (channels,
FAP file, segments) are here; the others live beside the code of their format (glTF and VRML in
coartic.face, the previews in coartic.runtime.preview, the rigs' curves and cues in
coartic.runtime.rigs and .rhubarb) and are named here by module, so that a run imports only the
formats it writes. `FaceAnimation` is what to write, computed once for every exporter: the
animation and its FAP sequence (the tongue through the model, blinks, expression). `ExportSettings`
holds how to write (names, face units, sound). The formats' modules do not import this one back
(but for annotations): it sits above them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from coartic.runtime.animate import Animation, write_channels_csv, write_segments_tsv
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import FaceUnits, FapSequence, animation_faps, write_fap

if TYPE_CHECKING:
    from rich.progress import Progress

    from coartic.speakers import SpeakerMapping
    from coartic.table import ParameterTable


@dataclass(frozen=True)
class RigOptions:
    """How the rigs' curves and cues are written (`--export arkit,visemes,rhubarb`; docs/RUNTIME.md)."""

    # Rhubarb's cues (coartic.runtime.rhubarb): which extended shapes of G H X the mouth has drawn,
    # the formats written, and Preston Blair's shape names in the DAT
    extended_shapes: str = "GHX"
    rhubarb_formats: tuple[str, ...] = ("tsv", "json")
    preston_blair: bool = False
    # the visemes' names: "meta" (Oculus), "rpm" (Ready Player Me, VRChat) or "vrm" (five vowels)
    viseme_names: str = "meta"
    # the curves' gain (exaggeration, 1 = the model's), each shape's own scale, smoothing (s, a Hann
    # window) and minimum hold (s; also Rhubarb's minimum cue duration when longer than its 7 cs)
    gain: float = 1.0
    shape_scale: tuple[tuple[str, float], ...] = ()
    smooth: float = 0.0
    hold: float = 0.0

    def __post_init__(self) -> None:
        import math

        for key, value, low, high in (("--rig-gain", self.gain, 0.0, 10.0), ("--rig-smooth", self.smooth, 0.0, 1.0),
                                      ("--rig-hold", self.hold, 0.0, 1.0)):
            if not (math.isfinite(value) and low <= value <= high):
                raise AnimationError(f"{key} {value!r}: must be within {low:g} to {high:g}")
        for name, factor in self.shape_scale:
            if not (math.isfinite(factor) and 0.0 <= factor <= 10.0):
                raise AnimationError(f"--rig-scale {name}={factor!r}: a scale is within 0 to 10")
        if self.viseme_names not in ("meta", "rpm", "vrm"):
            raise AnimationError(f"--viseme-names {self.viseme_names!r}: choose meta, rpm, vrm (Meta/Oculus, "
                                 "Ready Player Me/VRChat, VRM)")


def parse_shape_scale(spec: str | None) -> tuple[tuple[str, float], ...]:
    """`--rig-scale jawOpen=0.8,mouthFunnel=1.2` → ((name, factor), ...), checked for form."""
    out = []
    for item in (spec or "").split(","):
        if not item.strip():
            continue
        name, eq, value = item.partition("=")
        try:
            out.append((name.strip(), float(value)))
        except ValueError:
            raise AnimationError(f"--rig-scale {item.strip()!r}: expected NAME=FACTOR, e.g. jawOpen=0.8") from None
        if not eq or not name.strip():
            raise AnimationError(f"--rig-scale {item.strip()!r}: expected NAME=FACTOR, e.g. jawOpen=0.8")
    return tuple(out)


@dataclass
class ExportSettings:
    """How the exporters write one animation into `out`."""

    out: Path
    name: str  # the stem of the FAP, WAV, glTF and rig files (one ASCII word)
    face: FaceUnits  # FAPU of the face the table describes
    table: ParameterTable  # the table as given (the strip draws its targets)
    requested: tuple[str, ...] = ()  # segments.tsv: the phonemes asked for, and their source labels
    source: tuple[str, ...] = ()
    audio: Path | None = None  # the WAV beside the outputs
    progress: Progress | None = None
    mapping: SpeakerMapping | None = None
    gltf_morphs: str = "fap"  # the glTF's morph set: "fap" (one per FAP), "arkit" (ARKit's 52 names) or "eight"
    preview: str = "gif"
    rig: RigOptions = field(default_factory=RigOptions)
    files: dict[str, Path] = field(default_factory=dict)  # what earlier exporters wrote

    def audio_name(self) -> str | None:
        return self.audio.name if self.audio is not None else None


T = TypeVar("T")


@dataclass(frozen=True)
class FaceAnimation:
    """What every exporter is fed: the animation (channels, segments, neutral face, the table behind
    them) and its FAP sequence in the face's units, computed once (`of`) for all of them; what
    several exporters derive from the animation alike (the ARKit weights of the glTF and of the
    curves) is computed once too (`once`)."""

    animation: Animation
    faps: FapSequence
    _derived: dict[Any, Any] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def of(cls, animation: Animation, settings: ExportSettings) -> FaceAnimation:
        return cls(animation, animation_faps(animation, settings.face, settings.name))

    def once(self, derive: Callable[[Animation], T]) -> T:
        """`derive(self.animation)`, computed by the first exporter that asks, given to the others."""
        if derive not in self._derived:
            self._derived[derive] = derive(self.animation)
        out: T = self._derived[derive]
        return out


Exporter = Callable[[FaceAnimation, ExportSettings], dict[str, Path]]


def export_channels(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter: channels.csv."""
    path = settings.out / "channels.csv"
    write_channels_csv(path, fed.animation)
    return {"channels": path}


def export_segments(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter: segments.tsv, the phonemes asked for, shown and their source labels."""
    segments = fed.animation.segments
    path = settings.out / "segments.tsv"
    write_segments_tsv(path, segments, settings.requested or segments.labels, settings.source or segments.labels)
    return {"segments": path}


def export_fap(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter: NAME.fap."""
    path = settings.out / f"{settings.name}.fap"
    tmp = settings.out / f"{settings.name}.fap.part"
    write_fap(tmp, fed.faps)
    tmp.replace(path)
    return {"fap": path}


# name -> (module, function). Always written: channels, fap, segments; the others on request.
EXPORTERS: dict[str, tuple[str, str]] = {
    "channels": ("coartic.runtime.exporters", "export_channels"),
    "fap": ("coartic.runtime.exporters", "export_fap"),
    "segments": ("coartic.runtime.exporters", "export_segments"),
    "gltf": ("coartic.face.gltf", "export_gltf"),
    "vrml": ("coartic.face.vrml", "export_vrml"),
    "arkit": ("coartic.runtime.rigs", "export_arkit"),
    "visemes": ("coartic.runtime.rigs", "export_visemes"),
    "rhubarb": ("coartic.runtime.rhubarb", "export_rhubarb"),
    "plot": ("coartic.runtime.preview", "export_plot"),
    "preview": ("coartic.runtime.preview", "export_preview"),
}
# what `--export` accepts: the rigs' curves and cues
RIG_EXPORTS: tuple[str, ...] = ("arkit", "visemes", "rhubarb")
# the glTF's morph sets: one target per FAP (the default), ARKit's 52 names, or at most 8 per mesh
# (three.js up to r132 blends 8; coartic.face.gltf.limited_meshes)
GLTF_MORPH_SETS: tuple[str, ...] = ("fap", "arkit", "eight")


def parse_exports(spec: str | Sequence[str] | None) -> tuple[str, ...]:
    """`--export arkit,visemes,rhubarb` (or a list) → the names, checked, in RIG_EXPORTS order."""
    if spec is None:
        return ()
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    names = [s.strip() for s in items if s.strip()]
    bad = [n for n in names if n not in RIG_EXPORTS]
    if bad:
        raise AnimationError(f"--export {', '.join(bad)}: unknown; choose among {', '.join(RIG_EXPORTS)} "
                             "(comma-separated)")
    return tuple(n for n in RIG_EXPORTS if n in names)


def load_exporter(name: str) -> Exporter:
    module, function = EXPORTERS[name]
    fn: Exporter = getattr(import_module(module), function)
    return fn


def run_exports(animation: Animation, settings: ExportSettings, names: Sequence[str]) -> FaceAnimation:
    """Run the exporters `names` in order on one animation, fed to each with its FAP sequence
    computed once; every file is written atomically, the exact outputs first (an interrupted preview
    loses nothing else). What was written is in `settings.files` ({what: path}); returns what the
    exporters were fed."""
    if settings.gltf_morphs not in GLTF_MORPH_SETS:
        raise AnimationError(f"--gltf-morphs {settings.gltf_morphs!r}: choose {', '.join(GLTF_MORPH_SETS)}")
    fed = FaceAnimation.of(animation, settings)
    settings.out.mkdir(parents=True, exist_ok=True)
    for name in names:
        settings.files.update(load_exporter(name)(fed, settings))
    return fed
