"""What the face and rig tests share: the synthetic ground-truth table, Debian's three.js (r111,
the one the viewer and the glTF checks load), one utterance that shows every kind of mouth, what a
screenshot shows of the mouth and the upper face, and one Chromium for a test file's screenshots."""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import signal
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
THREE = Path("/usr/share/javascript/three")
# "# a p a f u l a #": a closure, a labiodental, a rounded vowel, a lateral, an open vowel (and a
# blink: the face's first is at 0.6 s)
APAFULA = """0.00 0.30 #
0.30 0.45 a
0.45 0.55 p
0.55 0.70 a
0.70 0.82 f
0.82 0.98 u
0.98 1.06 l
1.06 1.24 a
1.24 1.60 #
"""


def mouth_pixels(png: Path) -> dict[str, np.ndarray]:
    """Masks of lip-coloured, tooth-coloured and dark (mouth cavity) pixels."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    return {"lip": (img[..., 0] - img[..., 1] > 70) & (img[..., 0] > 100),
            "teeth": (img.min(axis=-1) > 170) & (img.max(axis=-1) - img.min(axis=-1) < 45),
            "dark": img.max(axis=-1) < 70}


def mouth_opening(png: Path) -> float:
    """Median over the central columns of the lips of the non-lip pixels between the top and the
    bottom lip pixel: 0 when the lips touch, the mouth's height in pixels when open."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    lip = (img[..., 0] - img[..., 1] > 70) & (img[..., 0] > 100)
    ys, xs = np.nonzero(lip)
    assert xs.size > 200, "no lips in the picture"
    x0, x1 = int(xs.min()), int(xs.max())
    centre, half = (x0 + x1) // 2, (x1 - x0) // 6
    gaps = []
    for x in range(centre - half, centre + half + 1):
        col = np.nonzero(lip[:, x])[0]
        gaps.append(0 if col.size == 0 else int(col.max() - col.min() + 1 - col.size))
    return float(np.median(gaps))


def upper_face(png: Path, eyes: tuple[int, int, int] | None = None) -> dict[str, float]:
    """The brows' height and the eyes' opening in a front view of the face (`coartic view
    --face-only`, the whole head in the picture): `sclera`, the eye-white pixels above the nose (the
    lids cover more of the eyes, fewer); `brow`, the mean row of the dark (brow-coloured) pixels in a
    band above the eyes (smaller: higher), its inner and outer thirds as `brow_inner`, `brow_outer`.
    `eyes` = (left eye's column, right eye's, the eyes' top row) of a reference picture (the
    neutral face's, `eyes_of`), so that every picture is measured in the same band; the band reaches
    30 mm above the eyes (the pixels' scale from the eyes' 64 mm apart) and the brows' 30 mm across."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    white = _eye_white(img)  # the teeth are white too
    cl, cr, top = eyes if eyes is not None else eyes_of(png)
    mm = abs(cl - cr) / 64.0
    dark = img.max(axis=-1) < 130
    rows = np.arange(img.shape[0])[:, None]
    band = (rows >= top - 30 * mm) & (rows <= top - 1.5 * mm)
    out: dict[str, float] = {"sclera": float(white.sum())}
    cols = np.arange(img.shape[1])[None, :]
    sides = [(c, 1 if c > (cl + cr) / 2 else -1) for c in (cl, cr)]
    for name, lo, hi in (("brow", -15.0, 15.0), ("brow_inner", -15.0, -5.0), ("brow_outer", 5.0, 15.0)):
        # the brow's inner third is the one nearer the other eye
        near = np.zeros(img.shape[:2], dtype=bool)
        for c, s in sides:
            off = (cols - c) * s  # mm... in pixels, outwards from the face's midline positive
            near |= (off >= lo * mm) & (off <= hi * mm)
        ys, _ = np.nonzero(dark & band & near)
        assert ys.size > 20 or name != "brow", f"{png}: no brows above the eyes"
        out[name] = float(ys.mean()) if ys.size else float("nan")  # a third may be too pale in a small picture
    return out


def _eye_white(img: np.ndarray) -> np.ndarray:
    """Eye-white pixels in the upper part of the picture (the teeth are white too, lower down; the
    viewer's background is a bluish grey: blue above red; the eyes are 20-30 % down a face-only
    picture at zoom 1.1-1.4)."""
    white: np.ndarray = (img.min(axis=-1) > 170) & (img.max(axis=-1) - img.min(axis=-1) < 45) & (img[..., 0] >= img[..., 2])
    white[int(0.45 * img.shape[0]):] = False
    white[:int(0.12 * img.shape[0])] = False  # the hair's edge against the background, at the top
    # nor the head's outline, where the background blends into the skin: 4 pixels off the background
    near = background = (img[..., 2] - img[..., 0] >= 4) & (img.min(axis=-1) > 200)
    for axis in (0, 1):
        for shift in range(-4, 5):
            near = near | np.roll(background, shift, axis=axis)
    return white & ~near


def eyes_of(png: Path) -> tuple[int, int, int]:
    """(left eye's column, right eye's column, the eyes' top row) in a front view: where the eye
    whites are, each side of the picture's middle."""
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    white = _eye_white(img)
    ys, xs = np.nonzero(white)
    assert xs.size > 40, f"{png}: no eyes in the picture"
    mid = img.shape[1] / 2
    return int(xs[xs > mid].mean()), int(xs[xs < mid].mean()), int(ys.min())


class Chromium:
    """One headless Chromium for a test file's screenshots of viewer pages.

    `coartic.face.viewer.screenshot` starts a Chromium for each picture, about 1 CPU-s of start-up
    for a picture that costs a fifth of that; the face tests take dozens. This one is started once
    and driven over its DevTools pipe (--remote-debugging-pipe: no port, no driver, the standard
    library only) with screenshot()'s flags, viewport and URL (`screenshot_url`), so each picture is
    the one screenshot() takes, pixel for pixel (test_view.py checks it on every kind of shot)."""

    def __init__(self, timeout: float = 60.0) -> None:
        from coartic.face.viewer import CHROMIUM_FLAGS, chromium_program

        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="coartic-chromium-")
        # Chromium reads commands from its fd 3 and writes answers to its fd 4, each a JSON message ended by NUL
        cmd_r, self._w = os.pipe()
        self._r, ans_w = os.pipe()
        # moved above 10 first, so that moving them onto 3 and 4 in the child cannot overwrite one with the other
        high = [fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in (cmd_r, ans_w)]
        os.close(cmd_r)
        os.close(ans_w)
        null = os.open(os.devnull, os.O_RDWR | os.O_CLOEXEC)
        argv = [chromium_program(), *CHROMIUM_FLAGS, f"--user-data-dir={self.profile}", "--remote-debugging-pipe",
                "about:blank"]
        try:
            self.pid = os.posix_spawn(argv[0], argv, os.environ, file_actions=[
                (os.POSIX_SPAWN_DUP2, high[0], 3), (os.POSIX_SPAWN_DUP2, high[1], 4),
                *[(os.POSIX_SPAWN_DUP2, null, k) for k in (0, 1, 2)]])
        finally:
            for fd in (*high, null):
                os.close(fd)
        self._buf = b""
        self._next_id = 0
        self._events: list[dict[str, Any]] = []
        self._size: tuple[int, int] | None = None
        self._view: tuple[Any, ...] | None = None  # the page and view on the screen (screenshot)
        page = next(t for t in self._call("Target.getTargets")["targetInfos"] if t["type"] == "page")
        self._session = self._call("Target.attachToTarget", targetId=page["targetId"], flatten=True)["sessionId"]
        self._call("Page.enable", session=True)

    def _message(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._r], [], [], left)[0]:
                raise RuntimeError(f"Chromium did not answer within {self.timeout:g} s")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed its DevTools pipe (it crashed or was killed)")
            self._buf += chunk
        msg, _, self._buf = self._buf.partition(b"\0")
        out: dict[str, Any] = json.loads(msg)
        return out

    def _call(self, method: str, session: bool = False, **params: Any) -> dict[str, Any]:
        self._next_id += 1
        msg: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self._session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            m = self._message(deadline)
            if m.get("id") == self._next_id:
                if "error" in m:
                    raise RuntimeError(f"Chromium's {method}: {m['error']}")
                result: dict[str, Any] = m["result"]
                return result
            if "method" in m:
                self._events.append(m)

    def _wait_event(self, name: str) -> None:
        deadline = time.monotonic() + self.timeout
        while not any(e["method"] == name for e in self._events):
            m = self._message(deadline)
            if "method" in m:
                self._events.append(m)
        self._events.clear()

    def screenshot(self, page: Path, png: Path, *, frame: int | None = None, face_only: int | None = None,
                   size: tuple[int, int] = (1130, 580), yaw: float | None = None, zoom: float | None = None,
                   section: bool = False) -> Path:
        """What `coartic.face.viewer.screenshot` takes with the same arguments.

        Another frame of the page and view on the screen is drawn by the page's own
        coarticView.show(frame / fps), what its load does for ?frame=, instead of loading the page
        again (parsing its glTF and setting up WebGL: 0.14 CPU-s of Chromium's a picture, against
        0.035). test_view.py compares such pictures with screenshot()'s too."""
        from coartic.face.viewer import screenshot_url

        if size != self._size:  # screenshot()'s --window-size: the page's viewport
            self._call("Emulation.setDeviceMetricsOverride", session=True, width=size[0], height=size[1],
                       deviceScaleFactor=1, mobile=False)
            self._size = size
            self._view = None
        st = Path(page).stat()
        view = (str(Path(page).resolve()), st.st_mtime_ns, st.st_size, face_only, yaw, zoom, section)
        # a frame the animation lacks is the page's load to refuse (its error), not show()'s to clamp
        if frame is None or view != self._view or not self._call("Runtime.evaluate", session=True, awaitPromise=True,
                                                                   expression=(
                "new Promise(done => { const v = window.coarticView, k = " + str(int(frame)) + ";"
                "if (!v || document.getElementById('error').textContent || !(k < v.nFrames)) { done(0); return; }"
                "v.show(k / v.fps); requestAnimationFrame(() => done(1)); })"))["result"].get("value"):
            self._events.clear()
            self._call("Page.navigate", session=True,
                       url=screenshot_url(page, frame=frame, face_only=face_only, yaw=yaw, zoom=zoom, section=section))
            self._wait_event("Page.loadEventFired")
            # the viewer draws in its load handler; a frame later the picture is on the screen
            self._call("Runtime.evaluate", session=True, awaitPromise=True, expression=(
                "new Promise(done => { const ready = () => (window.coarticView || document.getElementById('error')"
                ".textContent) ? requestAnimationFrame(() => done(1)) : setTimeout(ready, 5); ready(); })"))
            self._view = view
        data = self._call("Page.captureScreenshot", session=True, format="png")["data"]
        png.parent.mkdir(parents=True, exist_ok=True)
        partial = png.with_name(png.name + ".partial")
        partial.write_bytes(base64.b64decode(data))
        partial.replace(png)
        return png

    def close(self) -> None:
        try:
            self._call("Browser.close")
        except RuntimeError:
            os.kill(self.pid, signal.SIGKILL)
        finally:
            os.close(self._w)
            os.close(self._r)
            os.waitpid(self.pid, 0)
            shutil.rmtree(self.profile, ignore_errors=True)


def shared_chromium() -> Iterator[Chromium]:
    """A test file's Chromium (`browser = pytest.fixture(scope="module")(shared_chromium)`), or a skip
    when there is none."""
    from coartic.face.viewer import chromium_program

    try:
        chromium_program()
    except Exception as err:  # scripts/setup.sh installs it; without it there is nothing to look at
        pytest.skip(str(err))
    browser = Chromium()
    try:
        yield browser
    finally:
        browser.close()
