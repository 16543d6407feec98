"""The ASF/AMC reader on the real CMU and HDM05 files in ../shared/data (skipped when absent).

What the staged data allows to check (``../shared/data/README.md``, "ASF/AMC sets"):

* Every staged ASF and the one CMU 135 take read, retarget and look like a person.
* **The convention, against amc2bvh.** The cgspeed ``cmu_mb`` BVH files were made by
  amc2bvh from CMU's own ASF/AMC files. A bone with one or two dofs can only turn in
  the ways ``L = C M C^-1`` allows (``C`` from its ``axis`` line, ``M`` its dofs in
  their ASF order): so the BVH rotation of every such joint must factor exactly that
  way, with the VICON template's axis and dof lines (the same in every CMU ASF).
  Any other reading (``C^-1 M C``, dofs in the other order) leaves degrees over.
* **BVH and AMC of one motion give one canonical clip.** No trial is staged in both
  formats today (135_02 has no BVH, subject 14's BVH trials 14_07 and 14_08 have no
  AMC; the README says those were set aside), so the BVH 07_01 is written out as the
  ASF/AMC pair amc2bvh would have read (bone lengths from its offsets, dof values
  factored as above), read back, and both are retargeted: the canonical joints must
  agree. Should a trial come to be staged in both formats, the last test compares them.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from posecast.geometry.rotations import axis_mat, mat2euler
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.dataset.prepare import find_asf_for, read_motion
from posecast.offline.dataset.split import load_split_table, subject_of
from posecast.offline.motion.acclaim import (
    Asf,
    applied_rotation,
    bone_axis_matrix,
    read_acclaim,
    read_asf,
)
from posecast.offline.motion.bvh import Bvh, read_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.retarget import retarget
from posecast.offline.motion.rig import detect_rig, load_rigs
from posecast.skeleton import TOES, Joint

REPO_ROOT = Path(__file__).resolve().parents[3]
DATA = REPO_ROOT.parent / "shared" / "data"
CMU_AMC = DATA / "cmu_amc"

pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not CMU_AMC.is_dir(), reason=f"CMU ASF/AMC data not found at {CMU_AMC}"),
]

TEMPLATE = CMU_AMC / "135" / "135.asf.gz"
MB_FILES = ["mb/07/07_01.bvh.gz", "mb/05/05_02.bvh.gz"]

# cgspeed's cmu_mb joint names for the CMU ASF bones (what amc2bvh renamed).
MB_TO_ASF = {"Hips": "root"}
for _mb_side, _side in (("Left", "l"), ("Right", "r")):
    MB_TO_ASF.update(
        {
            f"{_side.upper()}HipJoint": f"{_side}hipjoint",
            f"{_mb_side}UpLeg": f"{_side}femur",
            f"{_mb_side}Leg": f"{_side}tibia",
            f"{_mb_side}Foot": f"{_side}foot",
            f"{_mb_side}ToeBase": f"{_side}toes",
            f"{_mb_side}Shoulder": f"{_side}clavicle",
            f"{_mb_side}Arm": f"{_side}humerus",
            f"{_mb_side}ForeArm": f"{_side}radius",
            f"{_mb_side}Hand": f"{_side}wrist",
            f"{_mb_side}FingerBase": f"{_side}hand",
            f"{_mb_side}HandIndex1": f"{_side}fingers",
            f"{_side.upper()}Thumb": f"{_side}thumb",
        }
    )
MB_TO_ASF.update(
    {
        "LowerBack": "lowerback",
        "Spine": "upperback",
        "Spine1": "thorax",
        "Neck": "lowerneck",
        "Neck1": "upperneck",
        "Head": "head",
    }
)


def _rows(name: str) -> list[dict[str, str]]:
    with (DATA / name).open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _angle_deg(m: np.ndarray) -> np.ndarray:
    cos = (np.trace(m, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _fit_dofs(a: np.ndarray, axes: str) -> np.ndarray:
    """Angles (radians) of the ``axes`` rotations applied in turn that best give ``a``.

    All CMU dof lists are in x, y, z order, so the ZYX factors with the absent ones
    dropped are the fit; what they leave out shows as the residual.
    """
    z, y, x = np.moveaxis(mat2euler(a, "ZYX"), -1, 0)
    by_axis = {"X": x, "Y": y, "Z": z}
    return np.stack([by_axis[ax] for ax in axes], axis=-1)


def _residual_deg(local: np.ndarray, c: np.ndarray, axes: str, inverse: bool = False) -> np.ndarray:
    """How far ``local`` is from the nearest ``C M C^-1`` (or ``C^-1 M C``), per frame."""
    if inverse:
        c = c.T
    a = c.T @ local @ c
    if axes in ("X", "Y", "Z"):
        i = "XYZ".index(axes)
        j, k = (i + 1) % 3, (i + 2) % 3
        theta = np.arctan2(a[..., k, j] - a[..., j, k], a[..., j, j] + a[..., k, k])
        fit = axis_mat(axes, theta)
    else:
        fit = applied_rotation(_fit_dofs(a, axes), axes)
    return _angle_deg(a @ np.swapaxes(fit, -1, -2))


@pytest.fixture(scope="module")
def template() -> Asf:
    return read_asf(TEMPLATE)


# --- the staged files read ---------------------------------------------------------------


def test_every_staged_skeleton_reads_with_cmu_units_and_bones(template: Asf) -> None:
    skeletons = sorted(DATA.glob("*_amc/*/*.as[fx]*"))
    assert len(skeletons) >= 15
    for path in skeletons:
        asf = read_asf(path)
        assert asf.unit_m == pytest.approx(0.0254 / 0.45), path
        assert asf.names == template.names, path
        for bone, ref in zip(asf.bones, template.bones, strict=True):
            assert (bone.axis_order, bone.dof) == (ref.axis_order, ref.dof), (path, bone.name)


def test_cmu_135_02_reads_with_its_skeleton_and_looks_like_a_person() -> None:
    amc = CMU_AMC / "135" / "135_02.amc.gz"
    assert find_asf_for(amc) == CMU_AMC / "135" / "135.asf.gz"
    bvh = read_motion(amc)
    row = next(r for r in _rows("index_amc.csv") if r["file"] == "cmu_amc/135/135_02.amc.gz")
    assert bvh.n_frames == int(row["frames"])  # AMC files have no T-pose frame
    rig = detect_rig(bvh, load_rigs())
    assert rig.name == "cmu_asf"
    clip = retarget(bvh, rig, name="135_02", subject=subject_of(amc))
    assert clip.subject == "135"
    assert abs(clip.n_frames - bvh.n_frames / 2) <= 1  # 120 -> 60 fps
    _, pos = clip.fk()
    # martial-arts walks, in low stances: the head well above the pelvis all the same
    assert 1.25 <= np.median(pos[:, Joint.HEAD, 1]) <= 1.75
    assert 0.7 <= np.median(pos[:, Joint.PELVIS, 1]) <= 1.05
    for toe in TOES:
        assert -0.01 <= np.percentile(pos[:, toe, 1], 5) <= 0.08, toe.name
    frames = derive_frames(clip)
    assert 0.1 < frames["contacts"].mean() < 0.95


def test_an_hdm05_take_reads_at_the_rate_its_name_says() -> None:
    amc = next(iter(sorted((DATA / "hdm05_amc" / "bd").glob("HDM_bd_squat*_120.amc.gz"))))
    bvh = read_motion(amc)
    assert bvh.fps == pytest.approx(120.0)
    assert subject_of(amc) == "bd"
    clip = retarget(bvh, detect_rig(bvh, load_rigs()), name=amc.name, subject="bd")
    _, pos = clip.fk()
    assert np.max(pos[:, Joint.HEAD, 1]) > 1.4  # stands up between the squats
    assert np.min(pos[:, Joint.PELVIS, 1]) < 0.8  # and squats


def test_every_asf_amc_subject_is_in_the_committed_split() -> None:
    table = load_split_table()
    rows = [r for r in _rows("index_amc.csv") if r["frames"]]
    assert len(rows) > 400
    for r in rows:
        assert subject_of(r["file"]) == str(r["subject"]).lstrip("0"), r["file"]
    subjects = {subject_of(r["file"]) for r in rows}
    assert subjects <= set(table), sorted(subjects - set(table))
    assert table["14"] == "test"  # its BVH trials are test already
    assert {table[s] for s in subjects - {"14", "135"}} == {"train", "val"}


# --- the convention, against amc2bvh ---------------------------------------------------


@pytest.mark.parametrize("rel", MB_FILES)
def test_amc2bvh_rotations_factor_as_c_m_c_inverse(template: Asf, rel: str) -> None:
    bvh = read_bvh(DATA / "cmu_bvh" / rel)
    rot, _ = bvh.local_transforms()
    rot = rot[1:]  # frame 1 is cgspeed's synthetic T-pose
    checked = 0
    for mb_name, bone_name in MB_TO_ASF.items():
        bone = template.bones[template.index(bone_name)]
        axes = "".join(d[-1].upper() for d in bone.dof)
        if not 1 <= len(axes) <= 2:
            continue
        local = rot[:, bvh.index(mb_name)]
        c = bone_axis_matrix(bone, template.angle_unit)
        ours = _residual_deg(local, c, axes)
        # BVH values have four decimals: a thousandth of a degree is all that is left.
        assert ours.max() < 1e-3, (mb_name, float(ours.max()))
        moving = np.median(_angle_deg(local)) > 5.0
        if moving:
            inverse = _residual_deg(local, c, axes, inverse=True)
            assert np.median(inverse) > 1.0, (mb_name, "C^-1 M C fits too")
            if len(axes) == 2:
                swapped = _residual_deg(local, c, axes[::-1])
                assert swapped.max() > 1.0, (mb_name, "either dof order fits")
        checked += 1
    assert checked == 18  # per side: knee, foot, toes, clavicle, elbow, wrist, hand, fingers, thumb


# --- one motion, both formats ------------------------------------------------------------


def _asf_amc_from_cmu_mb(bvh: Bvh, template: Asf) -> tuple[str, str]:
    """The ASF/AMC pair a cmu_mb BVH was converted from (its T-pose frame dropped)."""
    kids: dict[int, list[int]] = {}
    for i, j in enumerate(bvh.joints):
        kids.setdefault(j.parent, []).append(i)
    lines = [
        ":version 1.10",
        ":name from-bvh",
        ":units",
        "  mass 1.0",
        "  length 0.45",
        "  angle deg",
        ":root",
        "   order TX TY TZ RX RY RZ",
        "   axis XYZ",
        "   position 0 0 0",
        "   orientation 0 0 0",
        ":bonedata",
    ]
    for i, j in enumerate(bvh.joints[1:], start=1):
        bone = template.bones[template.index(MB_TO_ASF[j.name])]
        ends = [bvh.joints[k].offset for k in kids.get(i, [])] or [j.end_site]
        vec = np.asarray(ends[0], dtype=np.float64)
        assert all(np.allclose(e, vec) for e in ends)  # every child starts at the bone's end
        length = float(np.linalg.norm(vec))
        d = vec / length if length > 0 else np.zeros(3)
        lines += [
            "  begin",
            f"     name {bone.name}",
            f"     direction {d[0]:.12g} {d[1]:.12g} {d[2]:.12g}",
            f"     length {length:.12g}",
            "     axis {:.12g} {:.12g} {:.12g} {}".format(*bone.axis, bone.axis_order),
        ]
        if bone.dof:
            lines.append("     dof " + " ".join(bone.dof))
        lines.append("  end")
    lines += [":hierarchy", "  begin"]
    for p, cs in kids.items():
        if p >= 0:
            names = [MB_TO_ASF[bvh.joints[k].name] for k in (p, *cs)]
            lines.append("    " + " ".join(names))
    lines += ["  end", ""]

    rot, _ = bvh.local_transforms()
    rot = rot[1:]
    motion = bvh.motion[1:]
    per_bone: list[tuple[str, np.ndarray]] = []
    col = 0
    for i, j in enumerate(bvh.joints):
        bone = template.bones[template.index(MB_TO_ASF[j.name])]
        if i == 0:
            # root: positions, then Zrotation Yrotation Xrotation -> RX RY RZ
            pos = motion[:, col : col + 3]  # cmu_mb lengths are ASF units already
            rz, ry, rx = motion[:, col + 3], motion[:, col + 4], motion[:, col + 5]
            per_bone.append(("root", np.column_stack([pos, rx, ry, rz])))
        elif bone.dof:
            c = bone_axis_matrix(bone, template.angle_unit)
            axes = "".join(d[-1].upper() for d in bone.dof)
            per_bone.append((bone.name, np.degrees(_fit_dofs(c.T @ rot[:, i] @ c, axes))))
        col += len(j.channels)
    amc = [":FULLY-SPECIFIED", ":DEGREES"]
    for f in range(motion.shape[0]):
        amc.append(str(f + 1))
        amc += [name + " " + " ".join(f"{v:.9f}" for v in vals[f]) for name, vals in per_bone]
    return "\n".join(lines), "\n".join(amc) + "\n"


def _agreement_cm(a: CanonicalClip, b: CanonicalClip) -> tuple[float, float, float]:
    """Median and 95th-percentile joint distance, pelvis-relative, and the largest root
    path difference, in cm. Both clips are on the canonical skeleton (1.75 m), so the
    distances are already normalised to one body height."""
    assert a.n_frames == b.n_frames
    _, pa = a.fk()
    _, pb = b.fk()
    rel = np.linalg.norm((pa - pa[:, :1]) - (pb - pb[:, :1]), axis=-1) * 100.0
    root = np.linalg.norm(pa[:, 0] - pb[:, 0], axis=-1) * 100.0
    return float(np.median(rel)), float(np.percentile(rel, 95)), float(np.max(root))


def test_a_bvh_and_its_asf_amc_give_the_same_canonical_clip(tmp_path: Path, template) -> None:
    bvh = read_bvh(DATA / "cmu_bvh" / "mb" / "07" / "07_01.bvh.gz")
    asf_text, amc_text = _asf_amc_from_cmu_mb(bvh, template)
    (tmp_path / "07.asf").write_text(asf_text, "utf-8")
    (tmp_path / "07_01.amc").write_text(amc_text, "utf-8")
    amc = read_acclaim(tmp_path / "07.asf", tmp_path / "07_01.amc")
    assert amc.n_frames == bvh.n_frames - 1  # the README's frame-count relation
    rigs = load_rigs()
    from_bvh = retarget(bvh, detect_rig(bvh, rigs), name="07_01", subject="7")
    from_amc = retarget(amc, detect_rig(amc, rigs), name="07_01", subject="7")
    assert (from_bvh.rig, from_amc.rig) == ("cmu_mb", "cmu_asf")
    median, p95, root = _agreement_cm(from_bvh, from_amc)
    assert median < 0.01 and p95 < 0.05 and root < 0.05, (median, p95, root)


def test_trials_staged_in_both_formats_agree() -> None:
    bvh_rows = {r["motion_id"]: r for r in _rows("index.csv")}
    both = [r for r in _rows("index_amc.csv") if r["motion_id"] in bvh_rows]
    if not both:
        pytest.skip("no trial is staged both as BVH and as AMC (see the module docstring)")
    rigs = load_rigs()
    for row in both[:3]:
        b = read_bvh(DATA / bvh_rows[row["motion_id"]]["file"])
        a = read_motion(DATA / row["file"])
        assert a.n_frames == b.n_frames - 1, row["motion_id"]
        clips = [retarget(x, detect_rig(x, rigs), name="t", subject="s") for x in (b, a)]
        median, p95, _ = _agreement_cm(*clips)
        # the cmu_daz figure is another body: joint angles differ a little after MotionBuilder
        assert median < 2.0 and p95 < 6.0, (row["motion_id"], median, p95)
