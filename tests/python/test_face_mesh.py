"""The generated face, its feature points and its deformation by FAPs (coartic.face.mesh, deform)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic.face.deform import (
    BROW_RAISE,
    BROW_SQUEEZE,
    CHEEK_LIFT,
    JAW_FAP,
    LOWER_LID_FAPS,
    UPPER_FACE_FAPS,
    LIP_FAPS,
    TARGET_NAMES,
    TARGET_VALUE,
    TONGUE_ZONES,
    ZONES,
    FaceRig,
    build_rig,
    held_values,
    raised_cosine,
)
from coartic.face.mesh import EYE_X, PART_NAMES, build_face, eye_centre, min_angles
from coartic.io.labels import Segments
from coartic.runtime.animate import animate, neutral_posture, target_times
from coartic.runtime.fap import N_FAPS, FapSequence, channels_to_faps
from coartic.runtime.pipeline import speaker_face
from coartic.table import ParameterTable

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"


@pytest.fixture(scope="module")
def rig() -> FaceRig:
    return build_rig(build_face())


def one_frame(values: dict[int, int]) -> FapSequence:
    mask = np.zeros((1, N_FAPS), dtype=bool)
    vals = np.zeros((1, N_FAPS), dtype=np.int64)
    for fap, v in values.items():
        mask[0, fap - 1] = True
        vals[0, fap - 1] = v
    return FapSequence(name="t", fps=25.0, mask=mask, values=vals)


def displaced(rig: FaceRig, values: dict[int, int]) -> np.ndarray:
    return rig.pose(rig.weights(one_frame(values))[0]) - rig.mesh.vertices


def test_mesh_is_a_closed_mouth_face(rig: FaceRig) -> None:
    m = rig.mesh
    assert set(m.triangles) == set(PART_NAMES)
    for name, tris in m.triangles.items():
        assert tris.min() >= 0 and tris.max() < m.n_vertices
        assert np.all(m.part[tris] == PART_NAMES.index(name)), name
        p = m.vertices[tris]
        area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        assert area.min() > 1e-3, f"degenerate triangle in {name}"
    # neutral face: the two sides of the lip cut coincide (lips in contact), mouth 4-6 cm wide
    np.testing.assert_array_equal(m.vertices[m.slit[:, 0]], m.vertices[m.slit[:, 1]])
    assert 25.0 < m.mns < 35.0 and 40.0 < m.mw < 60.0
    assert m.upper[m.slit[:, 0]].all() and not m.upper[m.slit[:, 1]].any()
    # teeth, gums, tongue and mouth cavity lie behind the skin (hidden while the lips are closed)
    from coartic.face.mesh import skin_depth
    for part in ("upper_teeth", "lower_teeth", "cavity", "tongue"):
        v = m.vertices[m.in_part(part)]
        assert (skin_depth(v[:, 0], v[:, 1]) - v[:, 2]).min() > 1.5, part
    # the lips have thickness: their inner surfaces run 7-11 mm back from the lip line
    inner = m.in_part("skin") & (m.vertices[:, 2] < skin_depth(m.vertices[:, 0], m.vertices[:, 1]) - 1.0)
    assert inner.sum() > 100 and (skin_depth(np.zeros(1), np.zeros(1))[0] - m.vertices[inner, 2]).max() > 7.0
    # deterministic: the same face every time
    np.testing.assert_array_equal(build_face().vertices, m.vertices)


def test_single_feature_point_zone_is_the_raised_cosine(rig: FaceRig) -> None:
    """push_t_lip (17) is alone in its group: its field is exactly (1 + cos(π d / d_max)) / 2."""
    m = rig.mesh
    zone = next(z for z in ZONES if z.fap == 17)
    value = 400
    d = rig.targets[TARGET_NAMES.index("push_t_lip")] * value / TARGET_VALUE  # its field alone (no rounding)
    fp = m.vertices[m.feature_points[zone.point]]
    dist = np.linalg.norm(m.vertices - fp, axis=1)
    expected = value * rig.fapu(17) * raised_cosine(dist, zone.d_max)
    upper_skin = m.in_part("skin") & m.upper
    np.testing.assert_allclose(d[upper_skin, 2], expected[upper_skin], atol=1e-9)
    np.testing.assert_allclose(d[upper_skin, :2], 0.0, atol=1e-12)
    assert np.abs(d[~upper_skin]).max() < 1e-12  # never the lower lip, teeth or eyes
    assert (expected[upper_skin] == 0).sum() > 0.5 * upper_skin.sum()  # the zone ends at d_max


@pytest.mark.parametrize("fap", [f for f in LIP_FAPS if f not in (12, 13, 59, 60)])
def test_each_fap_moves_its_feature_point_exactly(rig: FaceRig, fap: int) -> None:
    m = rig.mesh
    value = 256
    d = displaced(rig, {fap: value})
    zone = next(z for z in ZONES if z.fap == fap)
    # corners carry an inner and an outer FAP on one vertex: each moves it half (coartic sends both)
    share = 0.5 if zone.point in ("2.4", "2.5", "8.3", "8.4") else 1.0
    np.testing.assert_allclose(d[m.feature_points[zone.point]], share * value * rig.fapu(fap) * np.array(zone.direction),
                               atol=1e-9)
    # the other feature points moving the same way stay put
    for other in ZONES:
        if other.group == zone.group and m.feature_points[other.point] != m.feature_points[zone.point]:
            assert abs(d[m.feature_points[other.point]] @ np.array(zone.direction)) < 1e-9, other.point


def test_deformation_is_linear_in_fap_values(rig: FaceRig) -> None:
    """At a given jaw opening, the lip FAPs add: each is one displacement field."""
    zero = {f: 0 for f in LIP_FAPS} | {JAW_FAP: 250}
    a = zero | {4: 120, 5: -300, 6: 80, 16: 50, 52: -300}
    b = zero | {4: -60, 5: 100, 7: 40, 17: 30, 51: 10}
    both = zero | {k: a[k] + b[k] for k in LIP_FAPS}
    lhs = displaced(rig, both)
    rhs = displaced(rig, a) + displaced(rig, b) - displaced(rig, zero)
    np.testing.assert_allclose(lhs, rhs, atol=1e-9)
    assert np.abs(displaced(rig, a) - displaced(rig, zero)).max() > 5.0


def test_jaw_turns_chin_and_lower_teeth_rigidly(rig: FaceRig) -> None:
    m = rig.mesh
    value = 400
    d = displaced(rig, {JAW_FAP: value})
    chin = d[m.feature_points["2.1"]]
    assert chin[1] == pytest.approx(-value * rig.fapu(JAW_FAP), abs=1e-9)  # open_jaw: chin down by value FAPU
    assert chin[2] < 0  # and back: it turns about the jaw joints
    teeth = m.in_part("lower_teeth")
    before, after = m.vertices[teeth], m.vertices[teeth] + d[teeth]
    dist0 = np.linalg.norm(before[:, None] - before[None], axis=2)
    dist1 = np.linalg.norm(after[:, None] - after[None], axis=2)
    np.testing.assert_allclose(dist1, dist0, atol=1e-9)
    assert np.abs(d[m.in_part("upper_teeth") | m.in_part("eyes")]).max() == 0.0
    assert np.abs(d[m.feature_points["2.2"]]).max() == 0.0  # the upper lip stays


def test_lower_lip_is_not_moved_twice(rig: FaceRig) -> None:
    """coartic's raise_b_midlip says where the lower lip goes, jaw included: with the jaw open by
    400 and the lip lowered by 400 FAPU, the lip lands 400 FAPU down, not jaw + lip."""
    m = rig.mesh
    d = displaced(rig, {JAW_FAP: 400, 5: -400, 16: 0})
    lip = d[m.feature_points["2.3"]]
    np.testing.assert_allclose(lip, [0.0, -400 * rig.fapu(5), 0.0], atol=1e-9)
    # a stream without lower-lip FAPs: the lip rides on the jaw; with raise_b_midlip 0, it stays
    assert displaced(rig, {JAW_FAP: 400})[m.feature_points["2.3"]][1] < -5.0
    assert displaced(rig, {JAW_FAP: 400, 5: 0, 16: 0})[m.feature_points["2.3"]] == pytest.approx([0, 0, 0], abs=1e-9)


def test_unsent_faps_hold_their_last_value() -> None:
    mask = np.zeros((3, N_FAPS), dtype=bool)
    vals = np.zeros((3, N_FAPS), dtype=np.int64)
    mask[0, 3], vals[0, 3] = True, 50
    mask[2, 3], vals[2, 3] = True, -7
    held = held_values(FapSequence(name="t", fps=25.0, mask=mask, values=vals))
    assert held[:, 3].tolist() == [50, 50, -7]
    assert held[:, 4].tolist() == [0, 0, 0]


def inner_lip_gaps(rig: FaceRig, faps: FapSequence) -> np.ndarray:
    """Per frame and per column of the lip cut: upper inner lip height minus lower, mm (< 0: pressed)."""
    pos = rig.pose(rig.weights(faps))
    slit = rig.mesh.slit
    gaps: np.ndarray = pos[:, slit[:, 0], 1] - pos[:, slit[:, 1], 1]
    return gaps


def test_lips_close_for_p_b_m_and_open_for_a(rig: FaceRig) -> None:
    """The synthetic session's ground truth driving the face: at the target frame of every /p b m/
    the lips touch along the whole cut; at /a/ they are parted by centimetres."""
    table = ParameterTable.load(GROUND_TRUTH)
    labels = ["#", "a", "b", "a", "m", "a", "p", "p", "a", "#"]
    durations = [0.2, 0.15, 0.07, 0.15, 0.08, 0.15, 0.06, 0.06, 0.18, 0.2]
    ends = np.round(np.cumsum(durations), 6)
    segs = Segments(tuple(labels), np.concatenate([[0.0], ends[:-1]]), ends)
    anim = animate(table, segs, 25.0)
    faps = channels_to_faps(anim.channels, neutral_posture(table), speaker_face(table), "apa", 25.0)
    gaps = inner_lip_gaps(rig, faps)
    frames = np.rint(target_times(table, segs, "LLO") * 25.0).astype(int)
    for i, ph in enumerate(labels):
        k = frames[i]
        if ph in "pbm":
            assert gaps[k].max() <= 0.0, f"/{ph}/ frame {k}: lips apart by {gaps[k].max():.2f} mm"
        elif ph == "a":
            assert gaps[k, gaps.shape[1] // 2] > 8.0, f"/a/ frame {k}: opening {gaps[k].max():.2f} mm"
            assert (gaps[k] > 0).all()
    assert len(TARGET_NAMES) == rig.targets.shape[0]
    assert rig.weights(faps).shape == (anim.n_frames, len(TARGET_NAMES))
    assert np.abs(rig.weights(faps)).max() < 1.0  # speech stays within one FAPU-1024 target
    assert TARGET_VALUE == 1024.0


@pytest.mark.festival
@pytest.mark.parametrize("stretch", [1.0, 0.6])
def test_the_readme_sentence_closes_every_p_b_m(rig: FaceRig, tmp_path: Path, stretch: float) -> None:
    """"Il babbo mangia la pappa." through Festival, at the normal and a fast rate: at the target
    frame of each of its seven /p b m/ the face's lips touch along the whole cut, and each /a/ is open."""
    from coartic.runtime.pipeline import speak_text

    table = ParameterTable.load(GROUND_TRUTH)
    out = speak_text("Il babbo mangia la pappa.", table, tmp_path, preview="none", stretch=stretch)
    gaps = inner_lip_gaps(rig, out.faps)
    segs = out.animation.segments
    frames = np.minimum(np.rint(target_times(table, segs, "LLO") * 25).astype(int), gaps.shape[0] - 1)
    bilabials = [i for i, ph in enumerate(segs.labels) if ph in ("p", "b", "m")]
    assert len(bilabials) == 7  # b, b b, m, p, p p (geminates are two segments)
    for i in bilabials:
        assert gaps[frames[i]].max() <= 0.0, f"/{segs.labels[i]}/ at frame {frames[i]}"
    for i, ph in enumerate(segs.labels):
        if ph == "a":
            assert gaps[frames[i], gaps.shape[1] // 2] > 3.0, f"/a/ at frame {frames[i]}"


def test_no_slivers_and_a_closed_head(rig: FaceRig) -> None:
    """Every triangle of every part has all its angles >= 8.5 degrees (the old mask had 318 slivers,
    down to 0.2 degrees); the skull is a closed surface (every edge shared by two triangles)."""
    m = rig.mesh
    for name, tris in m.triangles.items():
        angles = min_angles(m.vertices, tris)
        assert angles.min() >= 8.5, f"{name}: a triangle with a {angles.min():.1f} degree angle"
    skull = m.triangles["skull"]
    first = int(np.flatnonzero(m.in_part("skull"))[0])
    head = skull[(skull < first + 642).all(axis=1)]  # the subdivided icosahedron, without the neck
    assert head.shape[0] == 1280
    edges = np.sort(np.concatenate([head[:, [0, 1]], head[:, [1, 2]], head[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    # normals are consistent: the skull's all point away from the head's centre
    p = m.vertices[skull]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert ((n * (p.mean(axis=1) - np.array([0.0, 40.0, 0.0]))).sum(axis=1) > 0).mean() > 0.95


def pipeline_faps(tmp_path: Path, labels: str, table: Path = GROUND_TRUTH) -> tuple[FapSequence, list[int], list[str]]:
    """FAPs of `labels` (TSV text) through coartic animate's pipeline, and the target frame of each
    segment (of LLO) with its label."""
    from coartic.runtime.pipeline import animate_file

    (tmp_path / "u.tsv").write_text(labels)
    t = ParameterTable.load(table)
    out = animate_file(tmp_path / "u.tsv", t, tmp_path / "out", preview="none")
    segs = out.animation.segments
    frames = np.rint(target_times(t, segs, "LLO") * out.faps.fps).astype(int).tolist()
    return out.faps, frames, list(segs.labels)


AFATAKA = ("start\tend\tlabel\n0.0\t0.20\t#\n0.20\t0.36\ta\n0.36\t0.48\tf\n0.48\t0.64\ta\n0.64\t0.74\tt\n"
           "0.74\t0.90\ta\n0.90\t1.00\tk\n1.00\t1.16\ta\n1.16\t1.36\tl\n1.36\t1.50\ta\n1.50\t1.70\t#\n")


def test_f_tucks_the_lower_lip_under_the_upper_incisors(rig: FaceRig, tmp_path: Path) -> None:
    """At /f/ the lower lip rolls in (pulled back 2.5 mm and up 1 mm by the table): its inner edge
    goes behind the upper incisors' labial face, above their edge, and touches the edge. At /a/ it
    is centimetres away."""
    faps, frames, labels = pipeline_faps(tmp_path, AFATAKA)
    pose = rig.pose(rig.weights(faps))
    m = rig.mesh
    teeth = m.in_part("upper_teeth")
    central = teeth & (np.abs(m.vertices[:, 0]) < 4.0)
    edge = central & (m.vertices[:, 1] < m.vertices[central, 1].min() + 0.3)
    lip = m.in_part("skin") & ~m.upper & (np.abs(m.vertices[:, 0]) < 4.0)
    for ph in ("f", "a"):
        k = frames[labels.index(ph)]
        inner = pose[k, m.feature_points["2.3"]]
        gap = np.linalg.norm(pose[k, lip][:, None] - pose[k, edge][None], axis=2).min()
        if ph == "f":
            assert inner[2] < pose[k, edge, 2].max() - 2.0  # behind the incisors' labial face
            assert inner[1] > pose[k, edge, 1].max()  # above their edge
            assert gap < 1.0, gap  # in contact (within a millimetre)
        else:
            assert gap > 8.0, gap


def test_tongue_faps_move_the_tongue_and_touch_at_t_and_k(rig: FaceRig, tmp_path: Path) -> None:
    """Each tongue FAP moves its feature point by exactly its value (relative to the jaw); the
    default tongue (the shipped table's: this ground truth has no tongue) touches the upper teeth's back at /t/
    and /l/ and the roof of the mouth at /k/, and is far from both at /a/."""
    m = rig.mesh
    for fap, (point, direction, _) in TONGUE_ZONES.items():
        d = displaced(rig, {fap: 300, JAW_FAP: 0})
        np.testing.assert_allclose(d[m.feature_points[point]], 300 * rig.fapu(fap) * direction, atol=1e-9)
        assert np.abs(d[~m.in_part("tongue")]).max() == 0.0
    # on an open jaw, raise_tongue_tip 0 keeps the tip where it was in the head
    assert np.abs(displaced(rig, {JAW_FAP: 300, 44: 0, 45: 0})[m.feature_points["6.1"], 1:]).max() < 1e-9
    faps, frames, labels = pipeline_faps(tmp_path, AFATAKA)
    assert faps.mask[:, [42, 43, 44, 45, 46]].all()
    pose = rig.pose(rig.weights(faps))
    upper_teeth, roof = m.in_part("upper_teeth"), m.in_part("cavity") & (m.vertices[:, 1] > 5.0)

    def gap(k: int, point: str, part: np.ndarray) -> float:
        return float(np.linalg.norm(pose[k, part] - pose[k, m.feature_points[point]], axis=1).min())

    assert gap(frames[labels.index("t")], "6.1", upper_teeth) < 2.0
    assert gap(frames[labels.index("l")], "6.1", upper_teeth) < 2.0
    assert gap(frames[labels.index("k")], "6.2", roof) < 2.0
    a = frames[labels.index("a")]
    assert gap(a, "6.1", upper_teeth) > 10.0 and gap(a, "6.2", roof) > 10.0


def test_blinks_close_the_eyes(rig: FaceRig, tmp_path: Path) -> None:
    """The FAP stream blinks (FAPs 19, 20): at a blink's peak the upper lids' edges are below the
    pupils; between blinks they are above the irises."""
    from coartic.runtime.fap import BLINK_FIRST_S, BLINK_SHAPE_S

    faps, _, _ = pipeline_faps(tmp_path, AFATAKA.replace("1.50\t1.70\t#", "1.50\t3.00\t#"))
    assert faps.mask[:, 18:20].all()
    pose = rig.pose(rig.weights(faps))
    peak = int(round((BLINK_FIRST_S + BLINK_SHAPE_S[0] + BLINK_SHAPE_S[1] / 2) * faps.fps))
    assert faps.values[peak, 18] > 1000 and faps.values[0, 18] == 0
    for side, fp in (("l", "3.1"), ("r", "3.2")):
        pupil = eye_centre(EYE_X if side == "l" else -EYE_X)[1]
        assert pose[peak, m_fp(rig, fp), 1] < pupil - 5.0
        assert pose[0, m_fp(rig, fp), 1] > pupil + 3.0


@pytest.mark.parametrize("fap", UPPER_FACE_FAPS)
def test_each_upper_face_fap_moves_its_point_and_not_the_lips(rig: FaceRig, fap: int) -> None:
    """The brows (31-38) and cheeks (41, 42) an emotion moves: each FAP moves its feature point by
    exactly value x FAPU (ENS; ES for the squeeze, the left brow's inner end to the face's right),
    moves only the skin, and nothing of the lips, jaw or teeth (the /p b m/ and /f v/ contacts are
    the lip FAPs' alone)."""
    m = rig.mesh
    d = displaced(rig, {fap: 300})
    fp = {**BROW_RAISE, **CHEEK_LIFT, **BROW_SQUEEZE}[fap]
    unit = m.es if fap in BROW_SQUEEZE else m.ens
    direction = {37: [-1, 0, 0], 38: [1, 0, 0]}.get(fap, [0, 1, 0])
    np.testing.assert_allclose(d[m.feature_points[fp]], 300 * unit / 1024 * np.array(direction), atol=1e-9)
    assert rig.fapu(fap) == unit / 1024
    moved = np.abs(d).max(axis=1) > 0
    assert moved.sum() > 40 and not (moved & ~m.in_part("skin")).any()
    mouth = (np.abs(m.vertices[:, 1]) < 16.0) & (np.abs(m.vertices[:, 0]) < 34.0)
    assert not (moved & mouth).any() and not moved[m.slit].any()
    # the brows' zones do not reach the other brow, nor the eye's lower half
    assert not (moved & (m.vertices[:, 1] < 62.0) & (fap not in CHEEK_LIFT)).any()


def test_lower_lids_rise_and_upper_lids_open_wide(rig: FaceRig) -> None:
    """close_b_l/r_eyelid (21, 22) raise the lower lids' edges (3.3, 3.4) by value x IRISD / 1024;
    a negative close_t (19: eyeWide, surprise) lifts the upper lid's edge as much."""
    m = rig.mesh
    for fap, (side, fp) in LOWER_LID_FAPS.items():
        d = displaced(rig, {fap: 300})
        assert d[m.feature_points[fp], 1] == pytest.approx(300 * m.irisd / 1024, abs=1e-9)
        assert not (np.abs(d).max(axis=1) > 0)[~m.lower_lid[side]].any()
    assert displaced(rig, {19: -300})[m.feature_points["3.1"], 1] == pytest.approx(300 * m.irisd / 1024, abs=1e-9)


def m_fp(rig: FaceRig, fp: str) -> int:
    return rig.mesh.feature_points[fp]
