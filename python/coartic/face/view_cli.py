"""`coartic view OUT_DIR`: the page that plays a run's glTF face with its sound and channels."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape


_err = Console(stderr=True)
_out = Console()


def view_command(
    out_dir: Annotated[Path, typer.Argument(help="Output directory of coartic animate/speak run with --gltf.")],
    name: Annotated[str | None, typer.Option("--name", help="Which NAME.glb, when the directory has several.")] = None,
    serve: Annotated[bool, typer.Option("--serve", help="Serve the directory on 127.0.0.1 and wait (Ctrl-C stops).")] = False,
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="Port for --serve (0: any free port).")] = 8000,
    screenshot: Annotated[Path | None, typer.Option("--screenshot", help="Also save a PNG of the page from headless Chromium.")] = None,
    frame: Annotated[int | None, typer.Option("--frame", help="Frame shown in the screenshot (default 0).")] = None,
    yaw: Annotated[float | None, typer.Option("--yaw", help="Turn the face by this many degrees (+: its left side towards you).")] = None,
    view: Annotated[str | None, typer.Option("--view", help="Camera preset: front, three-quarter or profile.")] = None,
    section: Annotated[bool, typer.Option("--section", help="Cut the head along the midline (with --view profile: lips, teeth, tongue).")] = False,
    zoom: Annotated[float | None, typer.Option("--zoom", help="Bring the camera closer by this factor (2: the mouth twice as large).")] = None,
    face_only: Annotated[int | None, typer.Option("--face-only", min=1, help="Screenshot only the face, N x N pixels.")] = None,
    open_page: Annotated[bool, typer.Option("--open", help="Open the page in the default browser.")] = False,
) -> None:
    """Write OUT_DIR/view.html: the face (glTF) playing with its WAV in sync, the channels and a cursor.

    The page needs no network: open it from disk in a browser, or use --serve.
    """
    from coartic.face.viewer import (check_frame, make_server, page_query, screenshot as take_screenshot, view_yaw,
                                     write_page)

    if screenshot is not None:  # before Chromium runs
        from coartic.outputs import check_output_file

        check_output_file(screenshot, "--screenshot", "view.png", create_folder=True)
    turn = view_yaw(view, yaw)
    page = write_page(out_dir, name)
    if frame is not None:
        check_frame(page, frame)
    _out.print(f"viewer: {escape(str(page))}", highlight=False)
    if screenshot is not None:
        size = (face_only, face_only) if face_only else (1130, 580)
        png = take_screenshot(page, screenshot, frame=frame, face_only=face_only, size=size, yaw=turn, zoom=zoom, section=section)
        _out.print(f"screenshot: {escape(str(png))}", highlight=False)
    url = page.resolve().as_uri() + page_query(frame, turn, zoom, section)
    if serve:
        server = make_server(out_dir, port)
        host, used = str(server.server_address[0]), int(server.server_address[1])
        url = f"http://{host}:{used}/{page.name}" + page_query(frame, turn, zoom, section)
        _out.print(f"serving on {url} (Ctrl-C stops)", highlight=False)
    if open_page:
        import webbrowser

        if not webbrowser.open(url):
            _err.print(f"no browser found: open {escape(url)} yourself", highlight=False)
    if serve:
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            server.server_close()
