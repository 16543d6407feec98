"""The command line's face of the server config (posecast.online.config_cli)."""

import argparse
from dataclasses import fields

from posecast.online.config import ServerConfig
from posecast.online.config_cli import FLAGS_GIVEN, add_arguments, unknown_variables


def test_every_option_has_a_flag_except_the_secret() -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = vars(parser.parse_args(["--max-rate-hz", "30", "--dev", "--redis", "redis://r"]))
    assert args["max_rate_hz"] == 30 and args["dev"] is True and args["port"] is None
    assert "token_secret" not in args and "token_keys" not in args
    # Each flag typed is recorded as typed (an alias too), for the errors.
    given = args.pop(FLAGS_GIVEN)
    assert given == {"max_rate_hz": "--max-rate-hz", "dev": "--dev", "redis_url": "--redis"}
    assert set(args) == {f.name for f in fields(ServerConfig)} - {"token_secret", "token_keys"}
    assert FLAGS_GIVEN not in vars(parser.parse_args([]))


def test_unknown_variables_are_named_with_what_they_likely_meant() -> None:
    env = {
        "POSECAST_REDIS": "redis://redis:6379/0",  # the flag is --redis; the variable _URL
        "POSECAST_SAMPELS": "10",
        "POSECAST_SOMETHING": "1",
        "POSECAST_PORT": "8765",  # a setting
        "POSECAST_URL": "ws://x/",  # the SDK tools'
        "HOME": "/root",
    }
    assert unknown_variables(env) == {
        "POSECAST_REDIS": "POSECAST_REDIS_URL",
        "POSECAST_SAMPELS": "POSECAST_SAMPLES",
        "POSECAST_SOMETHING": None,
    }
    assert unknown_variables({f"POSECAST_{f.name.upper()}": "" for f in fields(ServerConfig)}) == {}
