"""The engine's settings (online.engine.config): the defaults, the derived switches and
every value refused at construction."""

from __future__ import annotations

import math

import pytest

from posecast.errors import ConfigError
from posecast.online.engine.config import MAX_SAMPLES, PAPER_LOOKAHEAD, EngineConfig


def test_the_default_is_present_and_the_papers_setting_one_option_away() -> None:
    cfg = EngineConfig()
    assert (cfg.lookahead, cfg.delayed_emission, cfg.delay) == (0, False, 0)
    paper = EngineConfig(lookahead=PAPER_LOOKAHEAD, delayed_emission=True)
    assert paper.delay == 10
    assert EngineConfig(lookahead=10).delay == 0  # the look-ahead alone delays nothing


def test_the_hand_reach_and_the_lean_are_parts_of_the_upper_body_pass() -> None:
    assert EngineConfig().reaches and EngineConfig().leans
    assert not EngineConfig(upper_body_ik=False).reaches
    assert not EngineConfig(upper_body_ik=False).leans
    assert not EngineConfig(hand_reach=False).reaches and EngineConfig(hand_reach=False).leans
    assert not EngineConfig(pelvis_lean=False).leans and EngineConfig(pelvis_lean=False).reaches


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"samples": 0}, "samples must be in"),
        ({"samples": MAX_SAMPLES + 1}, "samples must be in"),
        ({"lookahead": -1}, "lookahead must be >= 0"),
        ({"transition_frames": 0}, "transition_frames >= 1"),
        ({"outlier_factor": 0.0}, "outlier_factor must be > 0"),
        ({"stale_after_frames": 0}, "stale_after_frames >= 1"),
        ({"outlier_baseline": "max"}, "outlier_baseline must be 'min' or 'zero'"),
        ({"latent_scale": 0.0}, "latent_scale must be positive"),
        ({"latent_scale": math.nan}, "latent_scale must be positive"),
        ({"home_factor": -0.1}, "home_factor must be a finite number"),
        ({"home_factor": math.inf}, "home_factor must be a finite number"),
        ({"wrist_elbow": 1.5}, "wrist_elbow must be a share"),
        ({"waist_filter_hz": 0.0}, "waist_filter_hz must be positive"),
    ],
)
def test_bad_values_are_refused_with_a_config_error(change: dict[str, object], why: str) -> None:
    with pytest.raises(ConfigError, match=why) as info:
        EngineConfig(**change)  # type: ignore[arg-type]
    assert info.value.code == "CONFIG_INVALID"


def test_the_edges_of_each_range_are_accepted() -> None:
    for change in (
        {"samples": 1}, {"samples": MAX_SAMPLES}, {"home_factor": None}, {"home_factor": 0.0},
        {"wrist_elbow": 0.0}, {"wrist_elbow": 1.0}, {"waist_filter_hz": None},
        {"outlier_baseline": "zero"},
    ):  # fmt: skip
        EngineConfig(**change)  # type: ignore[arg-type]
