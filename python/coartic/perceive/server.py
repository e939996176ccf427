"""The participants' web pages (Flask, served by waitress): consent, one trial per page, thanks.

- `/` consent (a panel's identifier may come as `?pid=`: it is stored only as a keyed hash);
  agreeing starts the participant and sends them to `/p/<token>/`, their own link (also kept in a
  cookie): whoever reloads or comes back, with the link, the cookie or the panel identifier,
  continues at their first unanswered trial;
- `/p/<token>/` shows that trial; its form posts to `/p/<token>/answer`, which commits the answer
  (once: storage.Store.record) before it redirects back (post/redirect/get), so a reload never
  resubmits and an answer the server acknowledged is on disk;
- `/stimuli/<file>` the videos (range requests, so browsers can stream them).

Every page is a Jinja template with autoescaping on: nothing a study spec or a participant writes
reaches the page unescaped. The server binds 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

from flask import Flask, Response, abort, make_response, redirect, render_template, request, send_from_directory, url_for

from coartic.perceive.design import check_response
from coartic.perceive.storage import Participant, Store

COOKIE = "coartic_perceive"
MAX_FORM_BYTES = 64 * 1024


def load_study(study_dir: Path) -> tuple[dict[str, Any], str]:
    """The prepared study's manifest and its pseudonymisation key."""
    from coartic.perceive.stimuli import FORMAT
    from coartic.perceive.storage import StorageError

    manifest_path = study_dir / "study.json"
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        secret = (study_dir / "secret.key").read_text(encoding="utf-8").strip()
    except FileNotFoundError as err:
        raise StorageError(f"{study_dir}: not a prepared study (no {Path(err.filename).name}); run "
                           "`coartic perceive prepare STUDY.toml --out DIR` first") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise StorageError(f"{manifest_path}: not a study manifest ({err})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise StorageError(f"{manifest_path}: not a {FORMAT} manifest (prepared by another coartic?)")
    return manifest, secret


def default_db_url(study_dir: Path) -> str:
    return f"sqlite:///{(study_dir / 'results.sqlite').resolve()}"


def _paragraphs(text: str) -> list[str]:
    return [p.strip() for p in text.split("\n\n") if p.strip()]


def create_app(study_dir: Path, store: Store) -> Flask:
    """The Flask application of a prepared study whose answers go to `store`."""
    manifest = store.manifest
    here = Path(__file__).parent
    app = Flask(__name__, template_folder=str(here / "templates"), static_folder=str(here / "static"))
    app.config["MAX_CONTENT_LENGTH"] = MAX_FORM_BYTES
    stimuli_dir = (study_dir / "stimuli").resolve()
    files = {s["id"]: Path(s["file"]).name for s in manifest["stimuli"]}
    conditions_shown = {c["name"]: c for c in manifest["conditions"]}
    base = {"title": manifest["title"], "lang": manifest.get("lang", "en"), "error": None}

    @app.after_request
    def _headers(resp: Response) -> Response:
        resp.headers["X-Content-Type-Options"] = "nosniff"
        resp.headers["Referrer-Policy"] = "no-referrer"
        resp.headers["Content-Security-Policy"] = ("default-src 'self'; media-src 'self'; script-src 'self'; "
                                                   "style-src 'self'; frame-ancestors 'none'")
        if request.path.startswith("/p/") or request.path == "/":
            resp.headers["Cache-Control"] = "no-store"
        return resp

    def participant_or_404(token: str) -> Participant:
        p = store.by_token(token)
        if p is None:
            abort(404)
        return p

    def page(template: str, status: int = 200, **kw: Any) -> Response:
        return make_response(render_template(template, **{**base, **kw}), status)

    @app.get("/")
    def consent() -> Any:
        token = request.cookies.get(COOKIE)
        if token and store.by_token(token) is not None:
            return redirect(url_for("trial", token=token), 303)
        return page("consent.html", consent=_paragraphs(manifest["consent"]), pid=request.args.get("pid", "")[:200])

    @app.post("/start")
    def start() -> Any:
        pid = request.form.get("pid", "").strip()[:200] or None
        if request.form.get("agree") != "yes":
            return page("consent.html", 400, consent=_paragraphs(manifest["consent"]), pid=pid or "",
                        error="Please tick the box to agree before you start.")
        p = store.start(pid)
        resp = redirect(url_for("trial", token=p.token), 303)
        resp.set_cookie(COOKIE, p.token, max_age=180 * 86400, httponly=True, samesite="Lax")
        return resp

    def render_trial(p: Participant, k: int, error: str | None = None, status: int = 200) -> Response:
        t = p.trials[k]
        kind_choice = t["kind"] == "attention" or (manifest["design"] in ("intelligibility", "emotion")
                                                    and manifest["response"] == "choice")
        videos = [{"file": files[sid], "label": f"Face {chr(65 + n)}"} for n, sid in enumerate(t["stimuli"])]
        if kind_choice:
            options = t.get("choices") or manifest["choices"]
            mode, choices = "choice", [{"value": c, "label": c} for c in options]
        elif manifest["design"] == "preference":
            mode, choices = "choice", [{"value": str(n), "label": v["label"]} for n, v in enumerate(videos)]
        elif manifest["design"] == "mushra":
            mode, choices = "mushra", []
        else:
            mode, choices = "text", []
        reference = files[t["reference"]] if t.get("reference") and t["kind"] == "stimulus" else None
        return page("trial.html", status, trial=t, position=k, total=len(p.trials), token=p.token, videos=videos,
                    choices=choices, mode=mode, reference=reference, question=manifest["question"],
                    instructions=manifest["instructions"], replay=manifest["replay"] or mode == "mushra", error=error)

    @app.get("/p/<token>/")
    def trial(token: str) -> Any:
        p = participant_or_404(token)
        k = store.next_trial(p)
        if k is None:
            return page("done.html", code=manifest.get("completion_code", ""))
        return render_trial(p, k)

    @app.post("/p/<token>/answer")
    def answer(token: str) -> Any:
        p = participant_or_404(token)
        try:
            k = int(request.form.get("trial", ""))
        except ValueError:
            abort(400)
        if not 0 <= k < len(p.trials):
            abort(400)
        here_now = store.next_trial(p)
        if here_now is None or k != here_now:
            # answered before (a resubmission after a reload or a crash) or not reached yet: the first answer stands
            return redirect(url_for("trial", token=token), 303)
        t = p.trials[k]
        response = parse_response(manifest, t, request.form)
        problem = check_response(manifest, t, response)
        if problem is not None:
            return render_trial(p, k, error=problem.capitalize() + ".", status=400)
        rt = request.form.get("rt_ms", "")
        store.record(p, k, response, int(rt) if rt.isdigit() and len(rt) < 9 else None)
        return redirect(url_for("trial", token=token), 303)

    @app.get("/stimuli/<name>")
    def stimulus(name: str) -> Any:
        if name not in files.values():
            abort(404)
        return send_from_directory(stimuli_dir, name, conditional=True, max_age=3600)

    @app.errorhandler(404)
    def _not_found(_err: Any) -> Any:
        return page("message.html", 404, message="This page does not exist. If you were taking part, use the link "
                    "you were given (or go back to the first page).")

    @app.errorhandler(400)
    def _bad(_err: Any) -> Any:
        return page("message.html", 400, message="The answer could not be read; go back and answer again.")

    app.extensions["coartic_conditions"] = conditions_shown
    return app


def parse_response(manifest: dict[str, Any], trial: dict[str, Any], form: Any) -> Any:
    """The answer as stored: the choice, the typed text, the chosen condition, or each condition's rating."""
    if trial["kind"] == "attention" or (manifest["design"] in ("intelligibility", "emotion")
                                        and manifest["response"] == "choice"):
        return form.get("choice")
    if manifest["design"] in ("intelligibility", "emotion"):
        return form.get("text", "").strip()
    if manifest["design"] == "preference":
        c = form.get("choice", "")
        return trial["conditions"][int(c)] if c in ("0", "1") else None
    ratings: dict[str, int] = {}
    for n, cond in enumerate(trial["conditions"]):
        v = form.get(f"rating_{n}", "")
        if not v.isdigit():
            return None
        ratings[cond] = int(v)
    return ratings


def serve(study_dir: Path, db_url: str | None = None, host: str = "127.0.0.1", port: int = 8080, threads: int = 8,
          ready: Callable[[str], None] | None = None) -> None:
    """Serve the study until interrupted; `ready` is told the URL once the socket listens."""
    from waitress import create_server

    manifest, secret = load_study(study_dir)
    store = Store(db_url or default_db_url(study_dir), manifest, secret)
    app = create_app(study_dir, store)
    server: Any = create_server(app, host=host, port=port, threads=threads)
    shown_host = f"[{host}]" if ":" in host else host
    if ready is not None:
        ready(f"http://{shown_host}:{server.effective_port}/")
    try:
        server.run()
    finally:
        store.close()
