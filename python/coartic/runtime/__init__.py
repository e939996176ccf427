"""The animation runtime: parameter tables → channel trajectories, MPEG-4 FAP files, Festival speech, previews.

`coartic.runtime.pipeline` runs it end to end; see docs/RUNTIME.md.
"""

PREVIEW_FORMATS: tuple[str, ...] = ("gif", "mp4", "none")
