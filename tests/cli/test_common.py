"""The checks the commands share (posecast.cli.common), through the commands that make them."""

from __future__ import annotations

import pytest

from posecast.cli import main
from tests.cli.conftest import user_error


def test_an_unknown_backend_is_named_with_the_known_ones(capsys) -> None:
    err = user_error(capsys, main(["bench", "engine", "--backend", "cuda"]), "CONFIG_INVALID")
    assert "'cuda'" in err and "native, onnx, torch" in err.splitlines()[-1]


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["bench", "engine", "--players", "10,10"], "--players '10,10' names 10 twice"),
        (["bench", "engine", "--players", "1,10,1"], "--players '1,10,1' names 1 twice"),
        (["eval-apps", "--data", "d", "--samples", "4,4"], "--samples '4,4' names 4 twice"),
    ],
)
def test_a_count_listed_twice_is_refused(capsys, monkeypatch, argv: list[str], says: str) -> None:
    """``--players 10,10`` ran the same count twice and printed '10 (10 did not fit)'
    when one run fit and the other did not."""
    import posecast.offline.evaluation.engine_speed as speed

    monkeypatch.setattr(speed, "run_side_by_side", lambda *a: pytest.fail("it ran"))
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {says}: each count once" in err, err
