"""`coartic view OUT_DIR`: a static page that plays the face's glTF with its WAV, and the channels.

The page (OUT_DIR/view.html) holds everything but the sound: the .glb (base64), the channels and
the segments (JSON), and viewer.js, a small WebGL2 renderer written for this mesh. It needs no
network and no library; it opens from disk, or from `coartic view OUT_DIR --serve` on localhost.
The WAV is played by an <audio> element and is the clock: the face shows the weights at the
sound's current time, so picture and voice stay in sync.

`screenshot` runs a headless Chromium (Debian's `chromium`) on the page at a chosen frame: the
README's figure and the viewer's test come from it. `render_frames` draws every frame in one
Chromium (the perceptual tests' videos of the 3-D face, coartic.perceive.stimuli).
"""

from __future__ import annotations

import base64
import functools
import html
import io
import http.server
import json
import math
import os
import shutil
import subprocess
import tempfile
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from coartic.face.gltf import read_glb
from coartic.runtime.animate import read_channels_csv
from coartic.runtime.errors import AnimationError
from coartic.outputs import atomic_path, atomic_write_text

if TYPE_CHECKING:
    from PIL import Image

PAGE_NAME = "view.html"
# --view presets: how far the face is turned, in degrees (+: its left side towards the camera)
VIEW_PRESETS: dict[str, float] = {"front": 0.0, "three-quarter": 35.0, "profile": 90.0}
# headless, software WebGL (SwiftShader): the same picture on any machine, with or without a GPU
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                  "--hide-scrollbars", "--no-first-run", "--mute-audio")
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


@dataclass(frozen=True)
class ViewerInput:
    """What a run left in its output directory for the viewer."""

    glb: Path
    channels: Path
    segments: Path
    audio: Path | None


def find_inputs(out_dir: str | os.PathLike[str], name: str | None = None) -> ViewerInput:
    """The glTF (NAME.glb, or the only .glb), channels.csv, segments.tsv and the WAV the glTF names."""
    out = Path(out_dir)
    if not out.is_dir():
        raise AnimationError(f"{out}: not a directory (give the --out directory of coartic animate or speak)")
    if name is not None:
        glb = out / f"{name}.glb"
        if not glb.is_file():
            raise AnimationError(f"{glb}: no such glTF file")
    else:
        found = sorted(out.glob("*.glb"))
        if not found:
            raise AnimationError(f"{out}: no .glb file; run coartic animate or speak with --gltf and --out {out}")
        if len(found) > 1:
            raise AnimationError(f"{out}: several .glb files ({', '.join(p.name for p in found)}); choose one with --name")
        glb = found[0]
    for need in ("channels.csv", "segments.tsv"):
        if not (out / need).is_file():
            raise AnimationError(f"{out / need}: missing (written by coartic animate or speak with the .glb)")
    doc, _ = read_glb(glb)
    audio_name = (doc.get("asset", {}).get("extras") or {}).get("audio")
    audio = None
    if audio_name:
        audio = out / str(audio_name)
        if Path(str(audio_name)).name != audio_name or not audio.is_file():
            raise AnimationError(f"{glb}: its sound {audio_name!r} is not in {out}")
    return ViewerInput(glb=glb, channels=out / "channels.csv", segments=out / "segments.tsv", audio=audio)


def _segments(path: Path) -> list[tuple[float, float, str]]:
    rows = path.read_text(encoding="utf-8").splitlines()
    out = []
    for lineno, row in enumerate(rows[1:], start=2):
        cols = row.split("\t")
        try:
            out.append((float(cols[0]), float(cols[1]), cols[2]))
        except (ValueError, IndexError):
            raise AnimationError(f"{path}, line {lineno}: expected 'start end phoneme ...'") from None
    return out


def _script_json(value: Any) -> str:
    # inside <script>, "</" would end the element: JSON allows "<\/" for it
    return json.dumps(value, separators=(",", ":")).replace("</", "<\\/")


def page_html(inputs: ViewerInput) -> str:
    """The viewer page for `inputs`, as text."""
    doc, _ = read_glb(inputs.glb)
    extras = doc["asset"].get("extras") or {}
    times, channels = read_channels_csv(inputs.channels)
    fps = float(extras.get("fps", 25.0))
    name = doc["scenes"][0].get("name", inputs.glb.stem)
    data = {
        "glb": base64.b64encode(inputs.glb.read_bytes()).decode("ascii"),
        "name": name,
        "fps": fps,
        "audio": inputs.audio.name if inputs.audio else None,
        "times": [round(float(t), 6) for t in times],
        "duration": float(times[-1]) if times.size > 1 else 1.0 / fps,
        "channels": {c: [round(float(v), 4) for v in y] for c, y in channels.items()},
        "segments": _segments(inputs.segments),
    }
    js = resources.files("coartic.face").joinpath("viewer.js").read_text(encoding="utf-8")
    audio_tag = (f'<audio id="audio" preload="auto" src="{html.escape(urllib.parse.quote(inputs.audio.name))}"></audio>'
                 if inputs.audio else '<audio id="audio"></audio>')
    title = html.escape(f"{name} - coartic view")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font-family: sans-serif; margin: 12px; background: #f6f6f8; color: #222; }}
#row {{ display: flex; gap: 14px; align-items: flex-start; }}
#face {{ background: #eef0f4; border: 1px solid #ccc; }}
#plot {{ border: 1px solid #ccc; cursor: pointer; }}
#controls {{ margin-top: 8px; display: flex; gap: 8px; align-items: center; }}
#frame {{ width: 360px; }}
#error {{ color: #b00020; }}
body.face-only {{ margin: 0; overflow: hidden; }}
body.face-only #side, body.face-only h1 {{ display: none; }}
body.face-only #face {{ border: 0; position: fixed; left: 0; top: 0; }}
</style></head>
<body>
<h1 style="font-size:18px">{html.escape(name)}</h1>
<div id="row">
<canvas id="face" width="520" height="520"></canvas>
<div id="side">
<canvas id="plot" width="560" height="400"></canvas>
<div id="controls"><button id="play">play</button><button id="prev">&lt;</button><button id="next">&gt;</button>
<input id="frame" type="range" min="0" max="0" step="1" value="0"><span id="time"></span></div>
<p style="font-size:12px;color:#555">Drag the face to turn it; click the plot to jump. The sound sets the time.</p>
<div id="error"></div>
</div></div>
{audio_tag}
<script>window.COARTIC = {_script_json(data)};</script>
<script>{js}</script>
</body></html>
"""


def write_page(out_dir: str | os.PathLike[str], name: str | None = None) -> Path:
    """Write OUT_DIR/view.html (atomically) and return its path."""
    inputs = find_inputs(out_dir, name)
    page = Path(out_dir) / PAGE_NAME
    atomic_write_text(page, page_html(inputs))
    return page


def view_yaw(view: str | None, yaw: float | None) -> float | None:
    """The turn (degrees) for --view PRESET or --yaw DEG (not both); None for the page's default."""
    if view is not None and yaw is not None:
        raise AnimationError("give --view or --yaw, not both")
    if view is not None:
        if view not in VIEW_PRESETS:
            raise AnimationError(f"--view must be one of {', '.join(VIEW_PRESETS)}, got {view!r}")
        return VIEW_PRESETS[view]
    if yaw is not None and not (math.isfinite(yaw) and -180.0 <= yaw <= 180.0):
        raise AnimationError(f"--yaw must be an angle in degrees within -180..180, got {yaw!r}")
    return yaw


def page_frames(page: str | os.PathLike[str]) -> int:
    """How many frames the page's animation has (its frame times)."""
    text = Path(page).read_text(encoding="utf-8")
    start = text.index("window.COARTIC = ") + len("window.COARTIC = ")
    data = json.loads(text[start:text.index(";</script>", start)])  # JSON reads its "<\\/" as "</"
    return len(data["times"])


def check_frame(page: str | os.PathLike[str], frame: int) -> None:
    """Refuse a frame the page does not have (the page itself would show the nearest one)."""
    n = page_frames(page)
    if not 0 <= frame < n:
        raise AnimationError(f"--frame {frame} is outside 0..{n - 1}: {page} has {n} frames")


def page_query(frame: int | None, yaw: float | None, zoom: float | None = None, section: bool = False) -> str:
    """The page URL's query for a frame, a turn (degrees), a zoom and the midline section."""
    query: dict[str, str] = {}
    if frame is not None:
        query["frame"] = str(int(frame))
    if yaw is not None:
        query["yaw"] = repr(math.radians(float(yaw)))
    if zoom is not None:
        if not (math.isfinite(zoom) and 0.2 <= zoom <= 10.0):
            raise AnimationError(f"--zoom must be within 0.2..10, got {zoom!r}")
        query["zoom"] = repr(float(zoom))
    if section:
        query["section"] = "1"
    return "?" + urllib.parse.urlencode(query) if query else ""


def chromium_program() -> str:
    for prog in CHROMIUM_NAMES:
        found = shutil.which(prog)
        if found:
            return found
    raise AnimationError("no Chromium on PATH (Debian package 'chromium'; scripts/setup.sh installs it)")


def _face_query(frame: int | None, face_only: int | None, yaw: float | None, zoom: float | None,
                section: bool) -> str:
    query = page_query(frame, yaw, zoom, section)
    if face_only is not None:
        query += ("&" if query else "?") + f"face={int(face_only)}"
    return query


def screenshot_url(page: str | os.PathLike[str], *, frame: int | None = None, face_only: int | None = None,
                   yaw: float | None = None, zoom: float | None = None, section: bool = False) -> str:
    """The file URL `screenshot` opens (the tests' shared Chromium opens the same one)."""
    return Path(page).resolve().as_uri() + _face_query(frame, face_only, yaw, zoom, section)


def screenshot(page: str | os.PathLike[str], png: str | os.PathLike[str], *, frame: int | None = None,
               face_only: int | None = None, size: tuple[int, int] = (1130, 580), yaw: float | None = None,
               zoom: float | None = None, section: bool = False, timeout: float = 60.0) -> Path:
    """A PNG of `page` at `frame` (or its first frame) from a headless Chromium with software WebGL.

    `face_only=N` shows only the face, on an N x N canvas at the top left; `yaw` turns it (degrees).
    """
    png = Path(png)
    with tempfile.TemporaryDirectory(prefix="coartic-chromium-") as profile:
        shot = Path(profile) / "shot.png"
        _run_chromium(page, _face_query(frame, face_only, yaw, zoom, section), profile, size, [f"--screenshot={shot}"], timeout, "the screenshot")
        if not shot.is_file():
            raise AnimationError(f"Chromium wrote no screenshot of {page}")
        png.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(png) as tmp:
            shutil.copyfile(shot, tmp)
    return png


def _run_chromium(page: str | os.PathLike[str], query: str, profile: str, size: tuple[int, int], action: list[str],
                  timeout: float, what: str) -> subprocess.CompletedProcess[bytes]:
    """One headless Chromium (software WebGL, a throw-away profile) on `page` + `query`, doing `action`."""
    url = Path(page).resolve().as_uri() + query
    cmd: Sequence[str] = [
        chromium_program(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
        "--virtual-time-budget=5000", *action, url,
    ]
    try:
        proc = subprocess.run(cmd, capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise AnimationError(f"Chromium did not finish {what} of {page} within {timeout:g} s") from None
    if proc.returncode != 0:
        tail = proc.stderr.decode("utf-8", "replace").strip().splitlines()[-3:]
        raise AnimationError(f"Chromium failed on {page} (exit {proc.returncode}): {' | '.join(tail)}")
    return proc


# Rendering every frame in one Chromium: the time allowed per frame (software WebGL draws the face
# and encodes a PNG in ~0.1 s on one core), over a fixed start-up allowance.
RENDER_TIMEOUT_S = (60.0, 1.0)


def render_frames(page: str | os.PathLike[str], size: int, *, yaw: float | None = None,
                  zoom: float | None = None) -> list[Image.Image]:
    """Every frame of `page`'s animation as an RGB image of the face alone (`size` x `size`), drawn by
    viewer.js in one headless Chromium (the page's ?render=1 mode, read back with --dump-dom): the
    3-D face's frames for a video (coartic.perceive's stimuli), as `screenshot` shows one of them."""
    from PIL import Image

    n = page_frames(page)
    query = page_query(None, yaw, zoom) + ("&" if yaw is not None or zoom is not None else "?") + f"face={int(size)}&render=1"
    with tempfile.TemporaryDirectory(prefix="coartic-chromium-") as profile:
        proc = _run_chromium(page, query, profile, (size, size), ["--dump-dom"],
                             RENDER_TIMEOUT_S[0] + RENDER_TIMEOUT_S[1] * n, f"rendering {n} frames")
    dom = proc.stdout.decode("utf-8", "replace")
    start = dom.rfind('<pre id="frames">')  # the last: the page's script text precedes the element
    if start < 0:
        tail = proc.stderr.decode("utf-8", "replace").strip().splitlines()[-3:]
        raise AnimationError(f"Chromium drew no frames of {page}: {' | '.join(tail) or 'the page failed silently'}")
    lines = dom[start + len('<pre id="frames">'):dom.index("</pre>", start)].split()
    if len(lines) != n:
        raise AnimationError(f"Chromium drew {len(lines)} frames of {page}, which has {n}")
    prefix = "data:image/png;base64,"
    frames = []
    for line in lines:
        if not line.startswith(prefix):
            raise AnimationError(f"Chromium returned a frame of {page} that is not a PNG data URL")
        frames.append(Image.open(io.BytesIO(base64.b64decode(line[len(prefix):]))).convert("RGB"))
    return frames


class _Handler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        pass  # one line per request would bury the URL the user needs


def make_server(out_dir: str | os.PathLike[str], port: int = 8000) -> http.server.ThreadingHTTPServer:
    """An HTTP server for OUT_DIR on 127.0.0.1 only (port 0: any free port); the caller runs it."""
    handler = functools.partial(_Handler, directory=str(Path(out_dir).resolve()))
    try:
        return http.server.ThreadingHTTPServer(("127.0.0.1", port), handler)
    except OSError as err:
        raise AnimationError(f"cannot serve on 127.0.0.1:{port} ({err.strerror}); try another --port") from None
