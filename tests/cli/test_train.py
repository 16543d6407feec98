"""``posecast train`` and ``posecast export`` (posecast.cli.train)."""

from __future__ import annotations

from pathlib import Path

import pytest

from posecast.cli import main
from tests.cli.conftest import user_error


@pytest.mark.parametrize(
    ("network", "extra", "code"),
    [
        ("cvae", ["--steps", "0"], "CONFIG_INVALID"),
        ("cvae", ["--steps", "-3"], "CONFIG_INVALID"),
        ("cvae", ["--rot-weight", "-1"], "CONFIG_INVALID"),
        ("cvae", ["--rot-weight", "nan"], "CONFIG_INVALID"),
        ("cvae", ["--vel-weight", "-1"], "CONFIG_INVALID"),
        ("anomaly", ["--vel-weight", "1"], "CONFIG_INVALID"),
        ("cvae", ["--lower-weight", "0"], "CONFIG_INVALID"),
        ("anomaly", ["--lower-weight", "2"], "CONFIG_INVALID"),
        ("cvae", ["--threads", "0"], "CONFIG_INVALID"),
        ("cvae", ["--seed", "-1"], "CONFIG_INVALID"),
        ("cvae", ["--no-orientation"], "CONFIG_INVALID"),  # the 4-point layout has none
        ("ae", ["--layout", "hmd3"], "CONFIG_INVALID"),
        ("anomaly", ["--rot-weight", "10"], "CONFIG_INVALID"),
        ("anomaly", ["--hidden", "256"], "CONFIG_INVALID"),
        ("anomaly", ["--device", "auto"], "CONFIG_INVALID"),
        ("cvae", ["--hidden", "100"], "CONFIG_INVALID"),  # not a multiple of 64
        ("cvae", ["--hidden", "0"], "CONFIG_INVALID"),
        ("cvae", ["--window", "1"], "CONFIG_INVALID"),
        ("cvae", ["--batch", "0"], "CONFIG_INVALID"),
        ("cvae", ["--kl-weight", "-1"], "CONFIG_INVALID"),
        ("cvae", ["--budget-min", "inf"], "CONFIG_INVALID"),
        ("anomaly", ["--steps", "0"], "CONFIG_INVALID"),
        ("cvae", [], "DATASET_INVALID"),  # --data names no directory
        ("anomaly", [], "DATASET_INVALID"),
    ],
)
def test_train_user_error(
    tmp_path: Path, capsys, network: str, extra: list[str], code: str
) -> None:
    argv = ["train", network, "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "run")]
    user_error(capsys, main([*argv, *extra]), code)
    assert not (tmp_path / "run").exists()


def test_train_on_a_directory_that_is_not_a_dataset(tmp_path: Path, capsys) -> None:
    argv = ["train", "cvae", "--data", str(tmp_path), "--out", str(tmp_path / "run")]
    err = user_error(capsys, main(argv), "DATASET_INVALID")
    assert "posecast data prepare" in err


def test_export_user_error(tmp_path: Path, capsys) -> None:
    out = str(tmp_path / "models")
    user_error(capsys, main(["export", "--out", out]), "CONFIG_INVALID")  # nothing to export
    missing = tmp_path / "nope.pt"
    err = user_error(capsys, main(["export", "--out", out, "--ae", str(missing)]), "MODEL_INVALID")
    assert str(missing) in err
    rc = main(["export", "--out", out, "--ae", __file__, "--data", str(tmp_path / "nope")])
    user_error(capsys, rc, "DATASET_INVALID")


def test_train_device_auto_takes_cuda_only_where_torch_sees_one(monkeypatch) -> None:
    import torch

    from posecast.cli.train import train_device
    from posecast.errors import PosecastError

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert train_device("auto") == train_device("cpu") == "cpu"
    with pytest.raises(PosecastError, match="no CUDA device"):
        train_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert train_device("auto") == train_device("cuda") == "cuda"
