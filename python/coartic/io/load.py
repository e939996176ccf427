"""`load_trial`: the one entry point that reads a recording into a Trial (coartic.io.trial).

It picks the reader from the extension and the content (coartic.io.registry), reads and maps the
labels, and checks that they fit the data. It lives above the registry, whose readers build
Trials, and the Trial type lives below it: no module imports one that imports it back.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from coartic.io.errors import DataError, DataWarning
from coartic.io.labelmap import LabelMap, resolve_label_map
from coartic.io.labels import Segments, read_labels
from coartic.io.registry import ReadRequest, reader_for
from coartic.io.roles import RoleMap, ema_sensor_names, guess_axes, guess_ema_roles, resolve_role_map
from coartic.io.trial import PLAUSIBLE_POSITION_MM, Trial


def load_trial(
    path: str | PathLike[str],
    labels: str | PathLike[str] | Segments | None = None,
    label_map: LabelMap | Mapping[str, str] | str | PathLike[str] | None = None,
    role_map: RoleMap | Mapping[str, Any] | str | PathLike[str] | None = None,
    *,
    tier: str | None = None,
    units: str | None = None,
    meta: Mapping[str, Any] | None = None,
    allow_truncated: bool = False,
) -> Trial:
    """Read a recording and (optionally) its labels.

    `labels`: a label file (TextGrid, .lab, TSV) or Segments; `tier` picks the TextGrid tier (or
    the annotation level of an EMU bundle, whose own labels are used when `labels` is None).
    `label_map`: corpus labels → model phonemes (a built-in name such as 'german_sampa', a TSV or
    JSON file, or a dict); the default accepts only model phonemes and pauses.
    `role_map`: which marker/sensor is NOSE, UL, JAW...; for EMA also the axes (default: up is
    +z, forwards is -y, sensors guessed from usual names such as ul, ll, jw).
    `units` overrides the file's length unit. `allow_truncated` reads a C3D that holds fewer
    frames than its header declares (with a note in `meta["notes"]`) instead of refusing it.
    """
    p = Path(path)
    if p.is_dir():
        bundle = sorted(p.glob("*_annot.json"))  # an emuDB bundle directory: its annotation file is the recording
        raise DataError("is a folder, not a recording: give a file in it" +
                        (f" ({bundle[0]} for this emuDB bundle)" if bundle else ""), path=p)
    if not p.is_file():
        raise DataError("no such file", path=p)
    reader = reader_for(p)
    trial, own_labels = reader.read(p, ReadRequest(units=units, allow_truncated=allow_truncated,
                                                   level=tier if labels is None else None))
    if labels is None:
        if tier is not None and own_labels is None:  # not silently ignored
            raise DataError(f"tier {tier!r} was asked for, but no label file was given and this file carries no "
                            "labels of its own: give the TextGrid with --labels (labels= in Python)", path=p,
                            item=tier)
        labels = own_labels
    roles = resolve_role_map(role_map)
    if reader.sensors:
        roles = _sensor_roles(trial, roles, role_map is None, reader.axes)
    elif trial.kind == "markers" and ema_sensor_names(trial.marker_names):
        # e.g. a C3D export of an EMA system: its sensors, not a face marker set
        trial = replace(trial, kind="ema")
        trial.meta.setdefault("notes", []).append(
            "markers named as EMA sensors (UL, LL, jaw or tongue; no NOSE, EARs or CHIN): read as "
            "EMA sensors")
        roles = _sensor_roles(trial, roles, role_map is None, None)
    trial = replace(trial, roles=roles, meta={**trial.meta, **(dict(meta) if meta else {})})
    _warn_implausible_positions(trial)
    if labels is not None:
        segs = labels if isinstance(labels, Segments) else read_labels(labels, tier)
        trial = trial.with_labels(segs, resolve_label_map(label_map))
    return trial


def _warn_implausible_positions(trial: Trial) -> None:
    with np.errstate(invalid="ignore"):
        big = np.abs(trial.markers) > PLAUSIBLE_POSITION_MM
    if big.any():
        f, m, a = (int(i) for i in np.argwhere(big)[0])
        warnings.warn(f"{trial.source}: marker {trial.marker_names[m]!r} is at {trial.markers[f, m, a]:.6g} "
                      f"mm ({'xyz'[a]}, frame {f}; {int(big.any(axis=2).sum())} samples beyond "
                      f"{PLAUSIBLE_POSITION_MM:g} mm): not a position in a capture volume; check the "
                      "units", DataWarning, stacklevel=3)


def _sensor_roles(trial: Trial, given: RoleMap, guess: bool, axes: tuple[str, str] | None) -> RoleMap:
    """The roles of sensor data: a role map given is taken as it is, else the sensors are guessed
    from their usual names; axes the role map does not give are the format's, or (formats whose
    axes differ between labs) guessed from the sensors' geometry. What was guessed goes to the
    notes (printed by `coartic inspect`)."""
    roles = guess_ema_roles(trial.marker_names, RoleMap(source="guessed role map")) if guess else given
    said = []
    if guess:
        said.append("sensors guessed by name (" +
                    (", ".join(f"{r}={n}" for r, n in roles.roles.items()) or "none found") + ")")
    hint = trial.meta.get("roles_hint")
    if guess and hint and not {"UL", "LL"} <= roles.roles.keys():
        # a format that does not name its sensors (Carstens .pos): say how to name them
        raise DataError(str(hint), path=trial.source)
    if not given.axes_given:
        if axes is None:
            vertical, anterior, why = guess_axes(trial.markers, trial.marker_names, roles,
                                                 trial.planar_axis, trial.source)
            roles = replace(roles, vertical=vertical, anterior=anterior)
            said.append(f"axes guessed from the sensors: up = {vertical}, forwards = {anterior} ({why})")
        else:
            roles = replace(roles, vertical=axes[0], anterior=axes[1])
            said.append(f"axes assumed up = {axes[0]}, forwards = {axes[1]}")
    if said:
        trial.meta["notes"].append(("no role map: " if guess else "role map without axes: ")
                                   + "; ".join(said) + "; pass a role map to change")
    if trial.planar_axis is not None:
        lateral = 3 - roles.vertical_axis[0] - roles.anterior_axis[0]
        if lateral != trial.planar_axis:
            raise DataError(f"this file is midsagittal (axes {_axes_of(trial)} only), but the role "
                            f"map ({roles.source}) puts the vertical and anterior axes on "
                            f"{roles.vertical!r} and {roles.anterior!r}: they must be the two axes "
                            "the file has", path=trial.source)
    return roles


def _axes_of(trial: Trial) -> str:
    return " and ".join(a for k, a in enumerate("xyz") if k != trial.planar_axis)
