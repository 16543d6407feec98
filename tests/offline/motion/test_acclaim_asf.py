"""The ASF parser (offline.motion.acclaim_asf): every error names the file and the line."""

from __future__ import annotations

from pathlib import Path

import pytest

from posecast.errors import AcclaimError
from posecast.offline.motion.acclaim import read_acclaim
from posecast.offline.motion.acclaim_asf import read_asf

from .acclaim_fixtures import GOLDEN_ASF, write_text


def _asf_line(fragment: str) -> int:
    return next(i for i, ln in enumerate(GOLDEN_ASF.splitlines(), 1) if fragment in ln)


ASF_ERRORS = {
    "bad number": ("direction 1 0 0", "direction 1 x 0", "direction 1 0 0", "not a number"),
    "unknown dof": ("dof rz rx", "dof rz rw", "dof rz rx", "unknown dof"),
    "translation dof": ("dof ry\n", "dof ry tx\n", "dof ry", "not supported"),
    "bad axis order": ("30 XYZ", "30 XXY", "30 XYZ", "bad axis order"),
    "unknown hierarchy bone": ("arm forearm", "arm elbow", "arm forearm", "not a bone"),
    "second parent": ("forearm hand", "forearm hand arm", "forearm hand", "second parent"),
    "short axis": ("axis 0 0 30 XYZ", "axis 0 30 XYZ", "axis 0 0 30 XYZ", "axis"),
    "no length": ("     length 2.5\n", "", "name hand", "no 'length'"),
}


@pytest.mark.parametrize("kind", list(ASF_ERRORS))
def test_asf_errors_name_file_and_line(tmp_path: Path, golden, kind: str) -> None:
    old, new, at, why = ASF_ERRORS[kind]
    assert old in GOLDEN_ASF
    text = GOLDEN_ASF.replace(old, new, 1)
    line = _asf_line(at)
    if kind == "no length":
        # the forearm block loses its length: reported at the block's 'end'
        rows = text.splitlines()
        line = rows.index("     name hand") - 2  # 'end', then 'begin', 'id 4'
    path = write_text(tmp_path / "bad.asf", text, crlf=True)
    with pytest.raises(AcclaimError) as info:
        read_acclaim(path, golden[1])
    exc = info.value
    assert exc.code == "ACCLAIM_INVALID"
    assert exc.file == str(path)
    assert exc.line == line, str(exc)
    assert f"{path}:{line}: " in str(exc)
    assert why in str(exc)


def test_asf_structural_errors(tmp_path: Path, golden) -> None:
    cases = {
        "no hierarchy": (GOLDEN_ASF.split(":hierarchy")[0], "no :hierarchy"),
        "not an asf": ("HIERARCHY\nROOT Hips\n{\n", "not an ASF file"),
        "empty": ("", "empty"),
        "unclosed bone": (
            GOLDEN_ASF.replace("  end\n  begin\n     id 3", "  begin\n     id 3"),
            "'begin' inside",
        ),
        "unreachable bone": (
            GOLDEN_ASF.replace("    root spine stub\n", "    root spine\n"),
            "not reachable",
        ),
        "duplicate bone": (GOLDEN_ASF.replace("name stub", "name arm"), "duplicate bone name"),
    }
    for name, (text, why) in cases.items():
        path = write_text(tmp_path / f"{name.replace(' ', '_')}.asf", text)
        with pytest.raises(AcclaimError, match=why) as info:
            read_asf(path)
        assert info.value.file == str(path), name
        assert str(path) in str(info.value)
        assert info.value.line is not None, name
