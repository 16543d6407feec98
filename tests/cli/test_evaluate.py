"""``posecast eval`` and ``posecast eval-apps`` (posecast.cli.evaluate)."""

from __future__ import annotations

from pathlib import Path

import pytest

from posecast.cli import main
from tests.cli.conftest import user_error


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--variants", "foo"], "CONFIG_INVALID"),
        (["--variants", "cvae_ik,"], "CONFIG_INVALID"),
        (["--variants", "ae_ik", "--layout", "hmd3"], "CONFIG_INVALID"),
        (["--layout", "sites"], "CONFIG_INVALID"),
        (["--split", "holdout"], "CONFIG_INVALID"),
        (["--samples", "0"], "CONFIG_INVALID"),
        (["--samples", "100000000"], "CONFIG_INVALID"),
        (["--outlier-factor", "-1"], "CONFIG_INVALID"),
        (["--ik-max-drift", "-0.1"], "CONFIG_INVALID"),
        (["--ik-max-drift", "far"], "CONFIG_INVALID"),
        (["--ik-release-frames", "0"], "CONFIG_INVALID"),
        (["--wrist-elbow", "1.5"], "CONFIG_INVALID"),
        (["--wrist-elbow", "-0.1"], "CONFIG_INVALID"),
        (["--wrist-elbow", "nan"], "CONFIG_INVALID"),
        (["--lookahead", "-1"], "CONFIG_INVALID"),
        (["--lookahead", "256"], "CONFIG_INVALID"),
        (["--transition-frames", "0"], "CONFIG_INVALID"),
        (["--backend", "cuda"], "CONFIG_INVALID"),
        (["--json", "/no/such/dir/eval.json"], "CONFIG_INVALID"),
        (["--models", "/no/such/models"], "MODEL_INVALID"),
        ([], "DATASET_INVALID"),  # --data names no directory
    ],
)
def test_eval_user_error(tmp_path: Path, capsys, extra: list[str], code: str) -> None:
    rc = main(["eval", "--data", str(tmp_path / "nope"), *extra])
    user_error(capsys, rc, code)


def test_eval_takes_every_engine_switch_of_the_server() -> None:
    """``posecast eval --no-*`` are the server's engine switches, mapped to EngineConfig
    by the one mapping (config.engine_settings): a switch added to the server without
    its eval flag fails here, not with an AttributeError in a run."""
    from posecast.cli import build_parser
    from posecast.online.config import ENGINE_SWITCHES

    args = build_parser().parse_args(["eval", "--data", "d"])
    assert all(getattr(args, name) is False for name in ENGINE_SWITCHES)


def test_eval_of_a_directory_without_bvh_files(tmp_path: Path, capsys) -> None:
    user_error(capsys, main(["eval", "--bvh", str(tmp_path)]), "DATA_INVALID")


def test_eval_apps_user_error(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    data = tmp_path / "prepared"
    user_error(capsys, main(["eval-apps", "--data", str(data)]), "DATASET_INVALID")
    user_error(capsys, main(["eval-apps", "--data", str(data), "--runs", "0"]), "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--latent-scale", "0"])
    user_error(capsys, rc, "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--samples", "1,x"])
    user_error(capsys, rc, "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--samples", "10,100000000"])
    user_error(capsys, rc, "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--backend", "cuda"])
    user_error(capsys, rc, "CONFIG_INVALID")
    assert main(["data", "prepare", "--bvh", str(bvh_dir), "--out", str(data)]) == 0
    capsys.readouterr()
    rc = main(["eval-apps", "--data", str(data), "--clip", "no_such_clip"])
    err = user_error(capsys, rc, "CONFIG_INVALID")
    assert "01_01" in err  # the hint names the clips there are
