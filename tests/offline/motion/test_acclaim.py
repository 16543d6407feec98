"""The ASF/AMC reader (posecast.offline.motion.acclaim) on hand-made files.

The golden fixture's joint positions are computed here from the Acclaim definition
itself, as CMU's viewer composes it: a bone's frame in the world is
``W_b = W_parent C_parent^-1 C_b M_b`` (``C`` from the ``axis`` line, ``M`` from the
dof values, both applied in their listed order), the bone runs from its parent's end
along ``W_b C_b^-1 direction * length``. The reader instead builds BVH joints with
``L = C M C^-1``; both must put every joint in the same place.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from posecast.geometry.fk import fk_mat
from posecast.offline.motion.acclaim import DEFAULT_FPS, read_acclaim, read_asf
from posecast.offline.motion.bvh import Bvh
from posecast.offline.motion.retarget import retarget
from posecast.offline.motion.rig import detect_rig, load_rigs
from posecast.skeleton import Joint

from .acclaim_fixtures import (
    GOLDEN_AMC,
    GOLDEN_ASF,
    GOLDEN_FRAMES,
    UNIT_M,
    cmu_like_amc,
    cmu_like_asf,
    write_text,
)

NAMES = ("root", "spine", "arm", "forearm", "hand", "stub")


# --- the Acclaim definition, by hand ----------------------------------------------------


def _r(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    if axis == "X":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "Y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _applied(values: list[float], axes: str) -> np.ndarray:
    """The rotation that turns about ``axes[0]`` first, then ``axes[1]``, ..."""
    m = np.eye(3)
    for v, a in zip(values, axes, strict=True):
        m = _r(a, v) @ m
    return m


# bone: parent, direction, length, (axis angles, axis order), dof axes
BONES = {
    "spine": ("root", (0, 1, 0), 2.0, ([0, 0, 0], "XYZ"), "XYZ"),
    "arm": ("spine", (1, 0, 0), 3.0, ([0, 0, 30], "XYZ"), "ZX"),
    "forearm": ("arm", (0.6, 0, -0.8), 2.5, ([90, -30, 45], "XYZ"), "Y"),
    "hand": ("forearm", (0, 0, -1), 1.0, ([20, 30, 40], "ZYX"), "YZX"),
    "stub": ("root", (0, -1, 0), 1.5, ([0, 0, 0], "XYZ"), ""),
}


def _amc_frames(text: str) -> list[dict[str, list[float]]]:
    frames: list[dict[str, list[float]]] = []
    for line in text.splitlines():
        tok = line.split()
        if not tok or tok[0][0] in "#:":
            continue
        if len(tok) == 1:
            frames.append({})
        else:
            frames[-1][tok[0]] = [float(v) for v in tok[1:]]
    return frames


def _acclaim_fk(frame: dict[str, list[float]]) -> dict[str, np.ndarray]:
    """Joint (bone start) positions in file units, and ``<bone>.end`` for the leaves."""
    root = frame.get("root", [0.0] * 6)
    world = {"root": _applied(root[3:], "XYZ")}
    start = {"root": np.array(root[:3])}
    end = {"root": start["root"]}
    axis_c = {"root": np.eye(3)}
    for bone, (parent, d, length, (axis, order), dofs) in BONES.items():
        c = _applied(axis, order)
        m = _applied(frame.get(bone, []), dofs) if dofs else np.eye(3)
        axis_c[bone] = c
        world[bone] = world[parent] @ axis_c[parent].T @ c @ m
        start[bone] = end[parent]
        end[bone] = start[bone] + world[bone] @ c.T @ (np.array(d, float) * length)
    out = dict(start)
    out.update({f"{b}.end": end[b] for b in ("hand", "stub")})
    return out


def _positions(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions ``(F, J, 3)`` and rotations, as retargeting computes them."""
    rot, trans = bvh.local_transforms()
    root = trans[:, 0].copy()
    trans[:, 0] = 0.0
    gm, gp = fk_mat(rot, root, trans, bvh.parents)
    return gp, gm


def _ends(bvh: Bvh, gp: np.ndarray, gm: np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for j in bvh.joints:
        if j.end_site is not None:
            i = bvh.index(j.name)
            out[f"{j.name}.end"] = gp[:, i] + gm[:, i] @ np.asarray(j.end_site)
    return out


# --- the golden chain -------------------------------------------------------------------


def test_structure_units_and_channels(golden) -> None:
    asf_path, amc_path = golden
    bvh = read_acclaim(asf_path, amc_path)
    assert bvh.names == NAMES
    assert bvh.parents == (-1, 0, 1, 2, 3, 0)
    assert bvh.n_frames == GOLDEN_FRAMES
    assert bvh.fps == pytest.approx(DEFAULT_FPS)
    assert read_acclaim(asf_path, amc_path, fps=60.0).fps == pytest.approx(60.0)
    assert bvh.source == str(amc_path)
    # 1 unit = (1 / 0.45) inch; a joint's offset is its parent's direction x length
    assert read_asf(asf_path).unit_m == pytest.approx(0.056444, abs=1e-6)
    want = {
        "root": (0, 0, 0),
        "spine": (0, 0, 0),
        "arm": (0, 2, 0),
        "forearm": (3, 0, 0),
        "hand": (1.5, 0, -2.0),
        "stub": (0, 0, 0),
    }
    for j in bvh.joints:
        np.testing.assert_allclose(j.offset, np.array(want[j.name]) * UNIT_M, atol=1e-12)
    # leaves end at their own direction x length
    ends = {j.name: j.end_site for j in bvh.joints if j.end_site is not None}
    assert set(ends) == {"hand", "stub"}
    np.testing.assert_allclose(ends["hand"], np.array([0, 0, -1.0]) * UNIT_M)
    np.testing.assert_allclose(ends["stub"], np.array([0, -1.5, 0]) * UNIT_M)
    assert bvh.joints[0].channels[:3] == ("Xposition", "Yposition", "Zposition")
    assert {j.rotation_order for j in bvh.joints} == {"ZYX"}
    assert bvh.joints[0].line == GOLDEN_ASF.splitlines().index(":root") + 1


def test_first_frames_by_hand(golden) -> None:
    """Two frames small enough to work out on paper (file units, then metres)."""
    gp, gm = _positions(read_acclaim(*golden))
    # Frame 1: root at (1, 2, 3); the arm turns rz 90 in its frame C = Rz(30), which
    # is Rz(90) in the world too: the arm and all below it point up instead of along +X.
    f1 = np.array([[0, 0, 0], [0, 0, 0], [0, 2, 0], [0, 5, 0], [0, 6.5, -2.0], [0, 0, 0]])
    np.testing.assert_allclose(gp[0], (f1 + np.array([1, 2, 3])) * UNIT_M, atol=1e-9)
    # Frame 2: the root turns RY 90: (x, y, z) -> (z, y, -x).
    f2 = np.array([[0, 0, 0], [0, 0, 0], [0, 2, 0], [0, 2, -3], [-2.0, 2, -4.5], [0, 0, 0]])
    np.testing.assert_allclose(gp[1], f2 * UNIT_M, atol=1e-9)
    bvh = read_acclaim(*golden)
    ends = _ends(bvh, gp, gm)
    np.testing.assert_allclose(ends["hand.end"][0], np.array([1, 8.5, 0]) * UNIT_M, atol=1e-9)
    np.testing.assert_allclose(ends["hand.end"][1], np.array([-3, 2, -4.5]) * UNIT_M, atol=1e-9)
    np.testing.assert_allclose(ends["stub.end"][1], np.array([0, -1.5, 0]) * UNIT_M, atol=1e-9)


def test_every_frame_matches_the_acclaim_definition(golden) -> None:
    bvh = read_acclaim(*golden)
    gp, gm = _positions(bvh)
    ends = _ends(bvh, gp, gm)
    for f, frame in enumerate(_amc_frames(GOLDEN_AMC)):
        want = _acclaim_fk(frame)
        for name in NAMES:
            np.testing.assert_allclose(
                gp[f, bvh.index(name)], want[name] * UNIT_M, atol=1e-9, err_msg=f"{f} {name}"
            )
        for name in ("hand.end", "stub.end"):
            np.testing.assert_allclose(ends[name][f], want[name] * UNIT_M, atol=1e-9)


def test_the_dof_order_and_axis_order_matter(tmp_path: Path, golden) -> None:
    """Swapping the arm's ``rz rx`` or the hand's axis order moves the hand: they are read."""
    base = _positions(read_acclaim(*golden))[0]
    swapped = GOLDEN_ASF.replace("dof rz rx", "dof rx rz").replace("40 ZYX", "40 XYZ")
    asf = write_text(tmp_path / "swapped.asf", swapped)
    amc = write_text(tmp_path / "swapped_01.amc", GOLDEN_AMC)
    other = _positions(read_acclaim(asf, amc))[0]
    assert np.abs(other[2:] - base[2:]).max() > 0.01


@pytest.mark.parametrize(
    ("crlf", "gz", "asf_name"),
    [
        (True, False, "golden.asf"),
        (False, True, "golden.asf.gz"),
        (True, True, "golden.asx.gz"),
        (False, False, "golden.asx"),
    ],
    ids=["crlf", "gzip", "crlf-gzip-asx", "asx"],
)
def test_crlf_gzip_and_asx_read_the_same(
    tmp_path: Path, golden, crlf: bool, gz: bool, asf_name: str
) -> None:
    ref = read_acclaim(*golden)
    asf = write_text(tmp_path / "v" / asf_name, GOLDEN_ASF, crlf=crlf, gz=gz)
    amc = write_text(
        tmp_path / "v" / ("golden_01.amc" + (".gz" if gz else "")), GOLDEN_AMC, crlf=crlf, gz=gz
    )
    got = read_acclaim(asf, amc)
    assert got.names == ref.names
    np.testing.assert_array_equal(got.motion, ref.motion)
    assert [j.offset for j in got.joints] == [j.offset for j in ref.joints]


def test_radians(tmp_path: Path, golden) -> None:
    ref = read_acclaim(*golden)
    rad_asf = GOLDEN_ASF.replace("angle deg", "angle rad")
    for bone_axis in ("0 0 30", "90 -30 45", "20 30 40"):
        rad = " ".join(repr(math.radians(float(v))) for v in bone_axis.split())
        rad_asf = rad_asf.replace(f"axis {bone_axis} ", f"axis {rad} ")
    lines = []
    for ln in GOLDEN_AMC.replace(":DEGREES", ":RADIANS").splitlines():
        tok = ln.split()
        if len(tok) > 1 and tok[0] == "root":
            vals = tok[1:4] + [repr(math.radians(float(v))) for v in tok[4:]]
            ln = " ".join(["root", *vals])
        elif len(tok) > 1 and not tok[0].startswith("#"):
            ln = " ".join([tok[0], *(repr(math.radians(float(v))) for v in tok[1:])])
        lines.append(ln)
    got = read_acclaim(
        write_text(tmp_path / "rad.asf", rad_asf),
        write_text(tmp_path / "rad_01.amc", "\n".join(lines) + "\n"),
    )
    np.testing.assert_allclose(got.motion, ref.motion, atol=1e-9)


# --- CMU bone names: rig detection and retargeting ---------------------------------------


def test_cmu_names_pick_the_cmu_asf_rig_and_retarget(tmp_path: Path) -> None:
    asf = write_text(tmp_path / "77" / "77.asf", cmu_like_asf())
    amc = write_text(tmp_path / "77" / "77_01.amc", cmu_like_amc(seconds=1.0), crlf=True)
    bvh = read_acclaim(asf, amc)
    rig = detect_rig(bvh, load_rigs())
    assert rig.name == "cmu_asf"
    assert rig.unit_m == 1.0 and not rig.first_frame_is_tpose  # metres, no T-pose frame
    clip = retarget(bvh, rig, name="77_01", subject="77")
    assert clip.fps == 60.0
    assert clip.n_frames == (120 - 1) // 2 + 1  # nothing dropped, 120 -> 60 fps
    _, pos = clip.fk()
    assert np.median(pos[:, Joint.HEAD, 1]) > np.median(pos[:, Joint.PELVIS, 1]) + 0.4
    # the walk goes along +Z, 1.1 m/s, and the left foot is at +X in the ASF's frame
    assert pos[-1, Joint.PELVIS, 2] - pos[0, Joint.PELVIS, 2] > 0.5
    assert np.median(pos[:, Joint.LEFT_TOE, 0] - pos[:, Joint.RIGHT_TOE, 0]) > 0.05
    assert np.median(pos[:, Joint.LEFT_HAND, 0] - pos[:, Joint.RIGHT_HAND, 0]) > 0.1
