"""Server config (posecast.online.config): defaults, env, flags, validation, docs."""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
from dataclasses import fields
from pathlib import Path

import pytest

from posecast.errors import ConfigError, TokenExpiredError
from posecast.online.auth.tokens import mint, verify
from posecast.online.config import (
    BOUNDS,
    ENGINE_DEFAULTS_ONLY,
    ENGINE_SWITCHES,
    ServerConfig,
    engine_settings,
    setting_names,
)
from posecast.online.config_cli import FLAGS_GIVEN, add_arguments, option_help
from posecast.online.engine.config import EngineConfig

SECRET = "s" * 32
DOCS = Path(__file__).resolve().parents[2] / "docs" / "server.md"


def test_refuses_to_start_without_a_secret() -> None:
    with pytest.raises(ConfigError, match="POSECAST_TOKEN_SECRET"):
        ServerConfig.from_sources({})
    with pytest.raises(ConfigError, match="at least"):
        ServerConfig.from_sources({"POSECAST_TOKEN_SECRET": "short"})


def test_dev_invents_a_secret() -> None:
    a = ServerConfig.from_sources({}, {"dev": True})
    b = ServerConfig.from_sources({"POSECAST_DEV": "1"})
    assert len(a.token_secret) >= 32 and a.token_secret != b.token_secret


def test_flags_beat_env_beat_defaults() -> None:
    env = {"POSECAST_TOKEN_SECRET": SECRET, "POSECAST_PORT": "9000", "POSECAST_SAMPLES": "8"}
    cfg = ServerConfig.from_sources(env, {"port": 9100, "samples": None})
    assert (cfg.port, cfg.samples, cfg.tick_hz) == (9100, 8, 60.0)
    assert cfg.models_dir is None


def test_env_values_are_typed() -> None:
    env = {
        "POSECAST_TOKEN_SECRET": SECRET,
        "POSECAST_SLOW_CONSUMER_S": "0.5",
        "POSECAST_DEV": "false",
        "POSECAST_MODELS_DIR": "/tmp/m",
    }
    cfg = ServerConfig.from_sources(env)
    assert cfg.slow_consumer_s == 0.5 and cfg.dev is False and cfg.models_dir == "/tmp/m"
    with pytest.raises(ConfigError, match="POSECAST_PORT"):
        ServerConfig.from_sources({**env, "POSECAST_PORT": "eighty"})


@pytest.mark.parametrize(
    "change",
    [
        {"port": 70000},
        {"samples": 0},
        {"samples": 10**8},  # was a MemoryError traceback when the engine loaded
        {"lookahead": 256},  # welcome.lookahead_frames is 0 to 255: every client refused it
        {"tick_hz": 0.5},
        {"slow_consumer_s": 0.0},
        {"max_message_bytes": 100},  # below the protocol's floor
        {"max_players_per_room": 33},  # above the v1 maximum
        {"log_level": "LOUD"},
        {"wrist_elbow": 1.5},
        {"wrist_elbow": float("nan")},
        {"engine_threads": 65},  # the engine's pool takes 1 to 64
        {"socket_sndbuf_bytes": 2**31},  # SO_SNDBUF is a C int
        {"redis_node_ttl_s": float("nan")},
        {"redis_node_ttl_s": float("inf")},
        {"redis_url": "redis://127.0.0.1:notaport/0"},
        {"workers": "0"},
        {"workers": "257"},
        {"workers": "-1"},
        {"workers": "two"},
        {"workers": "\u0663"},  # an Arabic-Indic 3: isdigit(), but not a number to int()
    ],
)
def test_bad_values_are_refused_once_at_the_edge(change: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        ServerConfig(token_secret=SECRET, **change)  # type: ignore[arg-type]


def test_workers_is_a_number_or_auto_the_cpus_this_process_may_use() -> None:
    import os

    assert ServerConfig(token_secret=SECRET).worker_count == 1  # the default: one process
    auto = ServerConfig(token_secret=SECRET, workers="auto")
    assert auto.worker_count == len(os.sched_getaffinity(0))
    assert ServerConfig(token_secret=SECRET, workers="3").worker_count == 3
    cfg = ServerConfig.from_sources({"POSECAST_TOKEN_SECRET": SECRET, "POSECAST_WORKERS": "1"})
    assert cfg.worker_count == 1
    with pytest.raises(ConfigError, match="--workers 'many' must be auto or a number, 1 to 256"):
        ServerConfig.from_sources({}, {"workers": "many", "token_secret": SECRET},
                                  {"workers": "--workers"})  # fmt: skip


def test_the_secret_never_shows_in_repr() -> None:
    assert SECRET not in repr(ServerConfig(token_secret=SECRET))


def test_limits_follow_the_config() -> None:
    lim = ServerConfig(token_secret=SECRET, max_rate_hz=90, max_players_per_room=8).limits()
    assert (lim.max_rate_hz, lim.max_players, lim.max_message_bytes) == (90, 8, 8192)


def _flags(*argv: str) -> tuple[dict[str, object], dict[str, str]]:
    """The overrides and the flags as typed that ``posecast serve argv`` gives."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = vars(parser.parse_args(argv))
    return args, args.pop(FLAGS_GIVEN, {})


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--tick-hz", "nan"], "--tick-hz nan must be in [1, 240]"),
        (["--tick", "500"], "--tick-hz 500 must be in [1, 240]"),  # an abbreviation: the flag
        (["--port", "70000"], "--port 70000 must be in [0, 65535]"),
        (["--samples", "0"], "--samples 0 must be in [1, 4096]"),
        (["--engine-threads", "65"], "--engine-threads 65 must be in [1, 64]"),
        (["--slow-consumer-s", "0"], "--slow-consumer-s 0 must be in (0, 60] seconds"),
        (["--max-players-per-room", "33"], "--max-players-per-room 33 must be in [1, 32]"),
        (["--log-level", "LOUD"], "--log-level 'LOUD' unknown: one of DEBUG, INFO"),
        (["--node-id", "a b"], "--node-id 'a b' must be 1 to 64 of"),
        # The URL may carry a password: named, never shown; by the alias typed.
        (["--redis", "redis://u:pw@h:port/0"], "--redis is not a well-formed URL (not shown"),
        (["--redis-url", "http://u:pw@h/0"], "--redis-url must start with redis://"),
    ],
)
def test_a_bad_flag_is_named_as_typed_with_its_range(argv: list[str], said: str) -> None:
    """``posecast serve --tick-hz nan`` said ``tick_hz must be in [1, 240]``: the field,
    not the flag typed."""
    overrides, flags = _flags(*argv)
    env = {"POSECAST_TOKEN_SECRET": SECRET}
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources(env, overrides, flags)
    assert info.value.code == "CONFIG_INVALID"
    assert str(info.value).startswith(said), str(info.value)
    assert "pw" not in str(info.value)


@pytest.mark.parametrize(
    ("argv", "env", "named"),
    [
        (["--tick", "500"], {}, "--tick-hz"),  # typed: the flag, in full
        (["--tick-hz", "500"], {"POSECAST_TICK_HZ": "50"}, "--tick-hz"),  # a flag beats it
        ([], {"POSECAST_TICK_HZ": "500"}, "POSECAST_TICK_HZ"),
        ([], {"POSECAST_SAMPLES": "0"}, "POSECAST_SAMPLES"),
        (["--port", "1"], {"POSECAST_SAMPLES": "0"}, "POSECAST_SAMPLES"),
        (["--redis", "redis://h:p/0"], {}, "--redis"),  # an alias as typed
    ],
)
def test_setting_names_are_the_names_the_errors_use(
    argv: list[str], env: dict[str, str], named: str
) -> None:
    """One function names each setting as given, for the config's errors and the CLI's
    (serve's models-directory check computed its own from os.environ)."""
    overrides, flags = _flags(*argv)
    env = {"POSECAST_TOKEN_SECRET": SECRET, **env}
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources(env, overrides, flags)
    field = {"--tick-hz": "tick_hz", "POSECAST_TICK_HZ": "tick_hz", "--redis": "redis_url"}
    name = setting_names(env, overrides, flags)[field.get(named, "samples")]
    assert name == named and str(info.value).startswith((named + " ", named + "=")), info.value
    # a setting left at its default: by its variable when only variables were given
    default = setting_names(env, overrides, flags)["max_rooms"]
    assert default == ("--max-rooms" if argv else "POSECAST_MAX_ROOMS")


@pytest.mark.parametrize(
    ("argv", "env", "said"),
    [
        (["--tick-hz", "240.0000001"], {}, "--tick-hz 240.0000001 must be in [1, 240]"),
        ([], {"POSECAST_TICK_HZ": "0.9999999999"}, "POSECAST_TICK_HZ=0.9999999999 must be in"),
        (["--wrist-elbow", "1.000001"], {}, "--wrist-elbow 1.000001 must be in [0, 1]"),
        (["--token-leeway-s", "300.0000001"], {}, "--token-leeway-s 300.0000001 must be in"),
    ],
)
def test_a_float_just_out_of_range_is_shown_in_full(
    argv: list[str], env: dict[str, str], said: str
) -> None:
    """``--tick-hz 240.0000001`` said ``240 must be in [1, 240]``: ``:g`` rounded the
    value it refused into its range."""
    overrides, flags = _flags(*argv)
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources({"POSECAST_TOKEN_SECRET": SECRET, **env}, overrides, flags)
    assert str(info.value).startswith(said), str(info.value)


@pytest.mark.parametrize(
    "url",
    [
        "redis://default:s3cretPW/0",  # the password where a port goes: no user@
        "redis://default:s3cretPW@h:99999/0",
        "rediss://u:s3cretPW@[::1:6379/0",
        "redis://u:s3cretPW@h:-1/0",
    ],
)
@pytest.mark.parametrize("by", ["--redis", "POSECAST_REDIS_URL"])
def test_a_malformed_redis_url_is_refused_without_showing_any_of_it(url: str, by: str) -> None:
    """``--redis redis://default:s3cret/0`` said ``--redis: Port could not be cast to
    integer value as 's3cret'``: urllib's error quotes the URL, and docs/server.md
    promises a Redis URL is never shown."""
    env = {"POSECAST_TOKEN_SECRET": SECRET}
    overrides: dict[str, object] = {}
    flags: dict[str, str] = {}
    if by.startswith("--"):
        overrides, flags = _flags(by, url)
    else:
        env[by] = url
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources(env, overrides, flags)
    text = str(info.value)
    assert info.value.code == "CONFIG_INVALID"
    assert text.startswith(f"{by} is not a well-formed URL (not shown: it may hold a password)")
    assert "s3cret" not in text and "default" not in text and "99999" not in text, text
    assert "redis://user:password@host:6379/0" in text


@pytest.mark.parametrize(
    ("var", "raw", "said"),
    [
        ("POSECAST_TICK_HZ", "nan", "POSECAST_TICK_HZ=nan must be in [1, 240]"),
        ("POSECAST_SAMPLES", "100000000", "POSECAST_SAMPLES=100000000 must be in [1, 4096]"),
        ("POSECAST_WRIST_ELBOW", "1.5", "POSECAST_WRIST_ELBOW=1.5 must be in [0, 1]"),
        ("POSECAST_LAYOUTS", "hmd4", "POSECAST_LAYOUTS='hmd4' must be a comma-separated"),
        ("POSECAST_TOKEN_SECRET", "short", "POSECAST_TOKEN_SECRET has 5 characters"),
        ("POSECAST_REDIS_URL", "http://u:pw@h/0", "POSECAST_REDIS_URL must start with"),
    ],
)
def test_a_bad_variable_is_named_as_set(var: str, raw: str, said: str) -> None:
    env = {"POSECAST_TOKEN_SECRET": SECRET, var: raw}
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources(env)
    assert str(info.value).startswith(said), str(info.value)
    assert "pw" not in str(info.value) and "short" not in str(info.value)


def test_a_flag_is_named_over_the_variable_it_beats() -> None:
    env = {"POSECAST_TOKEN_SECRET": SECRET, "POSECAST_TICK_HZ": "60"}
    with pytest.raises(ConfigError, match=r"^--tick-hz 0\.5 must"):
        ServerConfig.from_sources(env, *_flags("--tick-hz", "0.5"))


def test_a_cross_field_error_names_both_options_as_given() -> None:
    """The node TTL against the Redis timeout: each named as the user gave it, one
    left at its default in the way the user sets the others."""
    env = {"POSECAST_TOKEN_SECRET": SECRET}
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources(env, *_flags("--redis-timeout-s", "2"))
    assert str(info.value) == (
        "--redis-node-ttl-s 3 must be above timeout + max(heartbeat / 2 + timeout,"
        " heartbeat) = 4.5 s, with --redis-timeout-s 2 and --redis-heartbeat-s 1: lower"
        " --redis-timeout-s or raise --redis-node-ttl-s"
    )
    # A container sets variables only: the default one is named by its variable too.
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources({**env, "POSECAST_REDIS_TIMEOUT_S": "2"})
    text = str(info.value)
    assert text.startswith("POSECAST_REDIS_NODE_TTL_S=3 must be above"), text
    assert "with POSECAST_REDIS_TIMEOUT_S=2 and POSECAST_REDIS_HEARTBEAT_S=1" in text, text
    assert "redis_" not in text, "a field's name, not what the user set"
    # Both sources at once; the TTL that must be twice the heartbeat names both.
    with pytest.raises(ConfigError) as info:
        env2 = {**env, "POSECAST_REDIS_HEARTBEAT_S": "1"}
        ServerConfig.from_sources(env2, *_flags("--redis-node-ttl-s", "1.5"))
    assert str(info.value) == (
        "--redis-node-ttl-s 1.5 must be at least twice POSECAST_REDIS_HEARTBEAT_S=1: lower"
        " POSECAST_REDIS_HEARTBEAT_S or raise --redis-node-ttl-s"
    )


def test_docs_table_lists_every_option_with_env_and_default() -> None:
    text = DOCS.read_text("utf-8")
    for name, env, default, _ in option_help():
        row = next((ln for ln in text.splitlines() if f"`{env}`" in ln), None)
        assert row is not None, f"docs/server.md lacks {env}"
        assert f"`--{name.replace('_', '-')}`" in row or name in ("token_secret", "token_keys"), row
        if default:
            assert re.search(rf"`{re.escape(default)}`", row), (name, default, row)
        if name in BOUNDS:  # and each number's range, as --help words it
            assert BOUNDS[name].words() in row, (name, BOUNDS[name].words(), row)


# The settings that 955c4be gave a top (before: checked from below only).
_CAPPED_ON_UPGRADE = [
    "token_leeway_s",
    "replay_cache",
    "frame_queue",
    "rate_burst",
    "control_rate_hz",
    "error_rate_hz",
    "max_watchers_per_room",
    "max_rooms",
    "max_connections",
    "conn_per_ip_per_min",
    "sockets_per_ip",
    "fatal_per_ip_per_min",
    "accepts_per_s",
    "reliable_queue",
    "slow_consumer_s",
    "hello_timeout_s",
    "idle_timeout_s",
    "drain_timeout_s",
    "close_timeout_s",
    "redis_heartbeat_s",
    "redis_node_ttl_s",
    "redis_timeout_s",
    "redis_backoff_max_s",
]


def test_docs_upgrading_note_lists_every_setting_now_refused_above_a_top() -> None:
    """The new ranges made a deployment with, say, POSECAST_IDLE_TIMEOUT_S=7200 exit
    with code 2 where it used to serve; docs/server.md's Upgrading note names each
    setting that gained a top, with the top it has."""
    text = DOCS.read_text("utf-8")
    assert "### Upgrading: numbers now refused" in text
    note = text.split("### Upgrading: numbers now refused", 1)[1].split("\n#", 1)[0]
    rows = re.findall(r"^\| `POSECAST_(\w+)`, `(--[\w-]+)` \| ([\d,]+)( s)? \|$", note, re.M)
    listed = {env.lower(): (flag, int(top.replace(",", "")), bool(s)) for env, flag, top, s in rows}
    assert list(listed) == _CAPPED_ON_UPGRADE, note
    for name, (flag, top, seconds) in listed.items():
        bounds = BOUNDS[name]
        assert flag == "--" + name.replace("_", "-")
        assert (top, seconds) == (bounds.high, bounds.unit == "seconds"), name
    # its example is what the server says
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources(
            {"POSECAST_TOKEN_SECRET": SECRET, "POSECAST_IDLE_TIMEOUT_S": "7200"}
        )
    assert f"`{info.value}`" in note


def test_every_number_has_finite_bounds_that_hold_its_default() -> None:
    """A numeric option added without a range would take inf (a guard turned off)."""
    numeric = {f.name for f in fields(ServerConfig) if str(f.type) in ("int", "float")}
    assert set(BOUNDS) == numeric
    for f in fields(ServerConfig):
        if f.name in BOUNDS:
            b = BOUNDS[f.name]
            assert math.isfinite(b.low) and math.isfinite(b.high), f.name
            assert b.holds(f.default), f.name


# Every setting that took inf before (times, rates, counts, checked only from below),
# and the absurd: a finite value past any deployment turns a guard off as well.
_UNBOUNDED_BEFORE = [
    ("--token-leeway-s", "inf", "(0, 300] seconds"),
    ("--token-leeway-s", "1e9", "(0, 300] seconds"),
    ("--control-rate-hz", "inf", "(0, 1000000]"),
    ("--error-rate-hz", "inf", "(0, 1000000]"),
    ("--accepts-per-s", "inf", "(0, 1000000]"),
    ("--slow-consumer-s", "inf", "(0, 60] seconds"),
    ("--hello-timeout-s", "inf", "(0, 60] seconds"),
    ("--idle-timeout-s", "inf", "(0, 3600] seconds"),
    ("--drain-timeout-s", "1e300", "(0, 600] seconds"),
    ("--close-timeout-s", "inf", "(0, 60] seconds"),
    ("--redis-heartbeat-s", "inf", "(0, 60] seconds"),
    ("--redis-timeout-s", "inf", "(0, 60] seconds"),
    ("--redis-backoff-max-s", "inf", "(0, 300] seconds"),
    ("--redis-node-ttl-s", "1e9", "(0, 600] seconds"),
    ("--replay-cache", "10000000000", "[1, 10000000]"),
    ("--rate-burst", "1000000000", "[1, 1000000]"),
    ("--max-rooms", "10000000", "[1, 1000000]"),
    ("--max-connections", "10000000", "[1, 1000000]"),
    ("--max-watchers-per-room", "10000000", "[1, 1000000]"),
    ("--conn-per-ip-per-min", "10000000", "[1, 1000000]"),
    ("--sockets-per-ip", "10000000", "[1, 1000000]"),
    ("--fatal-per-ip-per-min", "10000000", "[1, 1000000]"),
    ("--reliable-queue", "100000", "[1, 4096]"),
    ("--frame-queue", "100000", "[1, 256]"),
]


@pytest.mark.parametrize(("flag", "raw", "interval"), _UNBOUNDED_BEFORE)
def test_an_unbounded_value_is_refused_by_its_flag(flag: str, raw: str, interval: str) -> None:
    """``posecast serve --dev --token-leeway-s inf`` started, and with it no token ever
    expired (tokens.verify refuses only ``now - leeway >= exp``)."""
    overrides, flags = _flags(flag, raw)
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources({"POSECAST_TOKEN_SECRET": SECRET}, overrides, flags)
    assert info.value.code == "CONFIG_INVALID"
    value = overrides[flag[2:].replace("-", "_")]
    shown = repr(value).removesuffix(".0") if isinstance(value, float) else raw  # in full
    assert str(info.value) == f"{flag} {shown} must be in {interval}"


@pytest.mark.parametrize("raw", ["inf", "-inf", "nan", "1e999", "301"])
def test_a_non_finite_leeway_is_refused_by_its_variable(raw: str) -> None:
    with pytest.raises(ConfigError) as info:
        ServerConfig.from_sources({"POSECAST_TOKEN_SECRET": SECRET, "POSECAST_TOKEN_LEEWAY_S": raw})
    assert info.value.code == "CONFIG_INVALID"
    assert str(info.value).startswith("POSECAST_TOKEN_LEEWAY_S="), str(info.value)
    assert str(info.value).endswith("must be in (0, 300] seconds"), str(info.value)


def test_the_largest_leeway_still_lets_a_token_expire() -> None:
    """What the bound protects: with the leeway at its top, a token that expired longer
    ago is refused; inf (now refused) kept every token for ever."""
    leeway = BOUNDS["token_leeway_s"].high
    cfg = ServerConfig(token_secret=SECRET, token_leeway_s=leeway)
    tok = mint(cfg.secret_bytes, room="room", player="p1", now=1000.0, ttl_s=60)
    assert verify(cfg.secret_bytes, tok, now=1060.0 + leeway - 1, leeway_s=cfg.token_leeway_s)
    with pytest.raises(TokenExpiredError):
        verify(cfg.secret_bytes, tok, now=1060.0 + leeway, leeway_s=cfg.token_leeway_s)
    with pytest.raises(ConfigError):
        ServerConfig(token_secret=SECRET, token_leeway_s=math.inf)


@pytest.mark.parametrize("name", sorted(BOUNDS))
def test_every_bound_refuses_nan_inf_and_just_past_its_top(name: str) -> None:
    b = BOUNDS[name]
    for bad in (math.nan, math.inf, -math.inf, b.high + 1, b.low - 1):
        with pytest.raises(ConfigError, match=rf"^{name}="):
            ServerConfig(token_secret=SECRET, **{name: bad})  # type: ignore[arg-type]
    if b.above:
        with pytest.raises(ConfigError):
            ServerConfig(token_secret=SECRET, **{name: b.low})  # type: ignore[arg-type]


def test_no_upper_ik_reaches_the_engine() -> None:
    """``POSECAST_NO_UPPER_IK`` turns the engine's upper-body pass off; it is on by default."""
    from posecast.online.shell.app import PosecastServer

    for env, on in (({}, True), ({"POSECAST_NO_UPPER_IK": "1"}, False)):
        cfg = ServerConfig.from_sources({"POSECAST_TOKEN_SECRET": SECRET, **env})
        multi = PosecastServer(cfg)._default_engine()
        assert all(e.cfg.upper_body_ik is on for e in multi.engines.values())


@pytest.mark.parametrize(
    ("option", "attr"),
    [
        # SSI keeps samples whose feet sink below the floor pass's reach.
        ("no_floor_select", "floor_select"),
        # A guessed body stays at its height, not lowered toward a headset under its head.
        ("no_torso_span", "torso_span"),
        # A held foot stays where the other leg passes through it.
        ("no_legs_apart", "legs_apart"),
    ],
)
def test_a_no_option_turns_its_engine_step_off(option: str, attr: str) -> None:
    """``POSECAST_NO_*`` and its ``--no-*`` flag (the override) reach every engine;
    the step is on by default."""
    from posecast.online.shell.app import PosecastServer

    base = {"POSECAST_TOKEN_SECRET": SECRET}
    for cfg, on in (
        (ServerConfig.from_sources(base), True),
        (ServerConfig.from_sources({**base, "POSECAST_" + option.upper(): "1"}), False),
        (ServerConfig.from_sources(base, {option: True}), False),
    ):
        multi = PosecastServer(cfg)._default_engine()
        assert all(getattr(e.cfg, attr) is on for e in multi.engines.values())


# The server settings that set an engine field, with the field each sets.
ENGINE_SETTINGS = {
    f.name: f.metadata["engine"] for f in fields(ServerConfig) if f.metadata.get("engine")
}


def test_every_engine_setting_is_a_server_setting_or_left_at_its_default() -> None:
    """A new EngineConfig field cannot be forgotten: it gets a server setting (a flag
    and a POSECAST_* variable, declared with config._engine) or is listed as one the
    server leaves at the engine's default (shell/app.py and posecast eval mapped eleven by hand)."""
    engine = {f.name for f in fields(EngineConfig)}
    served = list(ENGINE_SETTINGS.values())
    assert len(set(served)) == len(served), "two server settings set one engine field"
    assert set(served) | ENGINE_DEFAULTS_ONLY == engine
    assert not set(served) & ENGINE_DEFAULTS_ONLY
    assert tuple(n for n in ENGINE_SETTINGS if n.startswith("no_")) == ENGINE_SWITCHES
    assert len(ENGINE_SWITCHES) == 12


def test_the_servers_engine_defaults_are_the_engines() -> None:
    assert ServerConfig(token_secret=SECRET).engine_config() == EngineConfig()


def _other(value: object) -> object:
    """A valid value other than a setting's default ``value``."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    assert isinstance(value, float)
    return value / 2


@pytest.mark.parametrize("name", sorted(ENGINE_SETTINGS))
def test_each_engine_setting_reaches_the_engine_by_its_flag_and_its_variable(name: str) -> None:
    """Every server setting of the engine, given by the flag and by the POSECAST_*
    variable generated from its field, sets its EngineConfig field, and only that."""
    (f,) = [f for f in fields(ServerConfig) if f.name == name]
    target = ENGINE_SETTINGS[name]
    value = _other(f.default)
    want = (not value) if f.metadata["off"] else value
    assert engine_settings({name: value}) == {target: want}
    flag = "--" + name.replace("_", "-")
    overrides, typed = _flags(*([flag] if value is True else [flag, str(value)]))
    base = {"POSECAST_TOKEN_SECRET": SECRET}
    variable = {"POSECAST_" + name.upper(): "1" if value is True else str(value)}
    for cfg in (
        ServerConfig.from_sources(base, overrides, typed),
        ServerConfig.from_sources({**base, **variable}),
    ):
        assert cfg.engine_config() == dataclasses.replace(EngineConfig(), **{target: want})


def test_the_node_key_must_outlive_the_slowest_round_trips() -> None:
    """Refreshes reach Redis up to timeout + max(heartbeat / 2 + timeout, heartbeat)
    apart (docs/scale-out.md, "A slow Redis"): a TTL not above that is refused."""
    ServerConfig(token_secret=SECRET)  # the defaults: 1 + max(0.5 + 1, 1) = 2.5 s < 3 s
    with pytest.raises(ConfigError, match=r"redis_node_ttl_s=3 .* = 4\.5 s"):
        ServerConfig(token_secret=SECRET, redis_timeout_s=2.0)
    ServerConfig(token_secret=SECRET, redis_timeout_s=2.0, redis_node_ttl_s=4.6)
