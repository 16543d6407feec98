"""Server configuration: one frozen dataclass, built once at the edge, passed down.

Every field can be set by a ``posecast serve`` flag (``--max-rate-hz``) or an
environment variable (``POSECAST_MAX_RATE_HZ``); a flag beats the environment,
which beats the default. :meth:`ServerConfig.from_sources` is the only place that
reads either; nothing below it looks at ``os.environ``. A bad value is named as the
user gave it (``--tick-hz nan``, ``POSECAST_TICK_HZ=nan``): the edge passes in where
each value came from. ``docs/server.md`` lists every option (a test keeps the table
in sync with this class).

The engine's settings among them (``samples``, ``lookahead``, ``tick_hz``,
``wrist_elbow`` and the ``no_*`` switches) are declared with :func:`_engine`, which
names the :class:`~posecast.online.engine.config.EngineConfig` field each one sets and
takes its default from there; :meth:`ServerConfig.engine_config` builds the engine's
config from those declarations, so no module maps them by hand. The engine's other
settings (:data:`ENGINE_DEFAULTS_ONLY`) are research knobs the server leaves at their
defaults.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Mapping
from dataclasses import InitVar, dataclass, field, fields
from typing import Any
from urllib.parse import urlsplit

from posecast.errors import ConfigError
from posecast.online.auth.keys import MIN_SECRET_BYTES, Key, KeySet, parse_key_set, secret_key
from posecast.online.auth.tokens import new_secret
from posecast.online.config_bounds import BOUNDS, MAX_SNDBUF_BYTES, Bounds
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ports import BACKENDS
from posecast.online.protocol.messages import Limits
from posecast.tracking.layouts import Layout

ENV_PREFIX = "POSECAST_"
_ID = re.compile(r"[A-Za-z0-9_.-]{1,64}")
MIN_SECRET_CHARS = MIN_SECRET_BYTES  # 32: chars of text, so at least as many bytes
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
MAX_WORKERS = 256
__all__ = [  # Bounds, BOUNDS, MAX_SNDBUF_BYTES: config_bounds's, kept importable here
    "BOUNDS",
    "ENGINE_DEFAULTS_ONLY",
    "ENGINE_SWITCHES",
    "ENV_PREFIX",
    "LOG_LEVELS",
    "MAX_SNDBUF_BYTES",
    "MAX_WORKERS",
    "MIN_SECRET_CHARS",
    "NO_FLAG",
    "Bounds",
    "ServerConfig",
    "engine_settings",
    "env_variable",
    "field_flags",
    "setting_names",
]


def _opt(default: Any, help: str, flags: tuple[str, ...] = (), **extra: Any) -> Any:
    """A config field; ``flags`` are extra spellings of its command-line flag."""
    return field(default=default, metadata={"help": help, "flags": flags}, **extra)


_ENGINE_DEFAULTS = {f.name: f.default for f in fields(EngineConfig)}


def _engine(name: str, help: str, *, off: bool = False) -> Any:
    """A config field that sets :class:`EngineConfig`'s field ``name``, with its
    default; ``off``: a ``no_*`` switch, on (``True``) to turn ``name`` off."""
    default = _ENGINE_DEFAULTS[name]
    meta = {"help": help, "flags": (), "engine": name, "off": off}
    return field(default=(not default) if off else default, metadata=meta)


@dataclass(frozen=True)
class ServerConfig:
    """Every knob of ``posecast serve``, with safe defaults (units in the names)."""

    host: str = _opt("127.0.0.1", "interface to bind (0.0.0.0 for all)")
    port: int = _opt(8765, "TCP port for WebSocket and HTTP (0: pick a free one)")
    workers: str = _opt(
        "1",
        "serving processes on the port: a number (1, the default: one process) or auto, "
        "the CPUs this process may run on; rooms span them (docs/scale-out.md, Workers; "
        "docs/engine.md, Capacity of a node: on 2-core AVX2 machines 1 holds more)",
    )
    token_secret: str = _opt(
        "", "HS256 key shared with the game backend (kid 'secret' in the key set)", repr=False
    )
    token_keys: str = _opt(
        "",
        "token key set, JWKS JSON: HS256 secrets and ES256/EdDSA public keys, each with "
        "a kid (docs/operations.md, Token keys)",
        repr=False,
    )
    token_keys_file: str = _opt(
        "", "file holding the token key set (JWKS JSON), re-read on SIGHUP and reload"
    )
    token_keys_reload_s: float = _opt(
        0.0, "seconds between re-reads of --token-keys-file (0: on SIGHUP only)"
    )
    dev: bool = _opt(False, "development mode: invent and print a secret if none is set")
    token_leeway_s: float = _opt(5.0, "clock skew allowed on token iat/exp, seconds")
    replay_cache: int = _opt(100_000, "ended-session token ids remembered (replay guard)")
    tick_hz: float = _engine("fps", "engine ticks per second (the shipped model runs at 60)")
    samples: int = _engine("samples", "latent samples per player, N")
    lookahead: int = _engine(
        "lookahead",
        "look-ahead tau in frames: how far a sample transition's blend has got at the frame "
        "it is detected (min(tau, 10)/10); with --delayed-emission poses lag frames by tau "
        "ticks (the paper: --lookahead 10 --delayed-emission)",
    )
    delayed_emission: bool = _engine(
        "delayed_emission",
        "emit each pose tau ticks after its frame (the paper's look-ahead: a transition is "
        "blended before the outlier shows) instead of at once; welcome.lookahead_frames "
        "says tau then, 0 otherwise",
    )
    no_upper_ik: bool = _engine(
        "upper_body_ik",
        "stream the poses without the upper-body pass (head on the headset, hands on the "
        "controllers): about twice the players per node, hands where the network puts them",
        off=True,
    )
    no_floor_ik: bool = _engine(
        "floor_ik",
        "stream the feet where the network and the contact IK put them, below the floor "
        "(y = 0) included, instead of lifting them onto it",
        off=True,
    )
    no_swing_clearance: bool = _engine(
        "swing_clearance",
        "lift only feet that are below the floor, not a toe that moves over it to the "
        "height real toes keep at its speed (the swing clearance)",
        off=True,
    )
    no_planted_toes: bool = _engine(
        "planted_toes",
        "let a toe in predicted contact near the floor slide with the network's, not "
        "at most 1 m/s (trailing it by up to 4 cm)",
        off=True,
    )
    no_knee_hinge: bool = _engine(
        "knee_hinge",
        "stream the knees as the network and the leg passes bend them, partly sideways "
        "included, instead of turning thigh and shin so each knee bends as a hinge",
        off=True,
    )
    no_elbow_hinge: bool = _engine(
        "elbow_hinge",
        "stream the elbows as the upper-body pass bends them, twisted about the upper arm "
        "included, instead of turning upper arm and forearm so each elbow bends as a hinge",
        off=True,
    )
    wrist_elbow: float = _engine(
        "wrist_elbow",
        "share of each shown elbow's placement taken from its controller's rotation (a "
        "straight wrist), the rest from the network's elbow; 0 for the network's alone",
    )
    no_hand_reach: bool = _engine(
        "hand_reach",
        "leave a guessed pelvis (a headset-only player, a tracker set without a waist) "
        "where the headset puts it, after the feet are planted, instead of moving it "
        "beforehand, horizontally toward a controller beyond the arm's reach too",
        off=True,
    )
    no_torso_span: bool = _engine(
        "torso_span",
        "leave a guessed body (a headset-only player, a tracker set without a waist) "
        "where the reach put it, the spine chain folding or stretching to the headset, "
        "instead of moving it along the line to the headset until the network's torso "
        "spans the distance",
        off=True,
    )
    no_legs_apart: bool = _engine(
        "legs_apart",
        "let the contact IK hold a planted foot where the other leg swings through it, "
        "instead of letting that foot give way toward the network's own just as far as "
        "keeps the legs apart",
        off=True,
    )
    no_pelvis_lean: bool = _engine(
        "pelvis_lean",
        "leave a guessed pelvis (a headset-only player, a tracker set without a waist) "
        "as the network turned it instead of leaning it so that the line to the head "
        "points at the headset, before the feet are planted",
        off=True,
    )
    no_floor_select: bool = _engine(
        "floor_select",
        "let SSI move to a sample with a foot deeper below the floor than the floor pass "
        "lifts (0.4 m), and stay on one, instead of leaving such samples out of the pool",
        off=True,
    )
    no_pelvis_smoothing: bool = _engine(
        "pelvis_smoothing",
        "stream each pose on its own frame's pelvis instead of a smoothed one (averaged 1:3 "
        "with the frame before's, a waist tracker's position its own; with "
        "--delayed-emission the 1-2-1 average with the frames either side), which takes "
        "the pelvis's shake out of the legs",
        off=True,
    )
    engine_threads: int = _opt(
        2,
        "threads of the engine's inference backend (the native kernels' pool, or ONNX "
        "Runtime's intra-op pool); 2 is both cores of the reference node",
    )
    backend: str = _opt(
        "native",
        "inference backend: native (the C extension; onnx where it does not load), onnx "
        "or torch (needs posecast[train])",
    )
    models_dir: str | None = _opt(None, "directory of ONNX models (default: shipped)")
    frame_queue: int = _opt(2, "frames kept per player between ticks; 1: only the newest")
    layouts: str = _opt(
        "hmd3+waist,hmd3",
        "tracker layouts served, comma-separated; each loads its model (sites: every "
        "tracker set, on one model)",
    )
    max_message_bytes: int = _opt(8192, "largest WebSocket message accepted, bytes")
    max_rate_hz: int = _opt(120, "frames per second one player may send (token bucket)")
    rate_burst: int = _opt(30, "frames a player may send above the rate in one burst")
    control_rate_hz: float = _opt(20.0, "non-frame messages per second per connection")
    error_rate_hz: float = _opt(20.0, "non-fatal error replies per second per connection")
    max_players_per_room: int = _opt(32, "players in one room (spectators not counted)")
    max_watchers_per_room: int = _opt(64, "spectators and backends watching one room")
    max_rooms: int = _opt(256, "rooms open at once on this server")
    max_connections: int = _opt(2048, "WebSocket connections open at once")
    max_watch_rooms: int = _opt(16, "extra rooms one backend may watch")
    conn_per_ip_per_min: int = _opt(120, "connection attempts per client IP per minute")
    sockets_per_ip: int = _opt(
        256, "sockets open at once per client IP, from the TCP accept (before any request)"
    )
    fatal_per_ip_per_min: int = _opt(
        20, "fatal protocol errors per client IP per minute before its connections get HTTP 429"
    )
    accepts_per_s: float = _opt(100.0, "new connections accepted per second, all IPs (HTTP 503)")
    reliable_queue: int = _opt(256, "control messages queued per client before SLOW_CONSUMER")
    socket_sndbuf_bytes: int = _opt(65536, "kernel send buffer per client (0: OS default)")
    slow_consumer_s: float = _opt(2.0, "seconds a client's writer may stay undrained")
    hello_timeout_s: float = _opt(5.0, "seconds to send hello after connecting")
    idle_timeout_s: float = _opt(60.0, "seconds a player may send nothing before TIMED_OUT")
    drain_timeout_s: float = _opt(5.0, "seconds shutdown waits for clients to drain")
    close_timeout_s: float = _opt(2.0, "seconds to wait for a closing handshake")
    log_level: str = _opt("INFO", "DEBUG, INFO, WARNING or ERROR (JSON lines on stderr)")
    # Scale-out (docs/scale-out.md). Empty redis_url: one embedded node, no Redis.
    redis_url: str = _opt(
        "", "Redis URL shared by all nodes, e.g. redis://redis:6379/0 (empty: one node)",
        repr=False, flags=("--redis",),
    )  # fmt: skip
    node_id: str = _opt("", "this node's id on the bus (empty: hostname plus a random suffix)")
    redis_prefix: str = _opt("posecast", "prefix of every Redis key and channel of this cluster")
    redis_heartbeat_s: float = _opt(1.0, "seconds between presence heartbeats and resyncs")
    redis_node_ttl_s: float = _opt(3.0, "seconds a silent node's players survive it")
    redis_timeout_s: float = _opt(1.0, "seconds one Redis round trip may take before a reconnect")
    redis_backoff_max_s: float = _opt(5.0, "longest wait between Redis reconnect attempts")

    # How the user gave each setting (``--tick-hz``, ``POSECAST_TICK_HZ``), for the
    # errors of the checks below; a setting not in it is named by its field. Not a field:
    # :meth:`from_sources` passes it in, nothing keeps it.
    sources: InitVar[Mapping[str, str] | None] = None

    def __post_init__(self, sources: Mapping[str, str] | None) -> None:
        _check(self, _Named(self, sources or {}))

    @property
    def worker_count(self) -> int:
        """How many serving processes: ``workers``, ``auto`` resolved to the CPUs this
        process may run on (its affinity, e.g. a container's cpuset); validated in
        ``__post_init__``."""
        if self.workers == "auto":
            return max(1, len(os.sched_getaffinity(0)))
        return int(self.workers)

    @property
    def served_layouts(self) -> tuple[Layout, ...]:
        """The tracker layouts this server accepts in ``hello`` (one model each);
        validated in ``__post_init__``."""
        return tuple(Layout(x) for x in self._layout_names())

    def _layout_names(self) -> tuple[str, ...]:
        return tuple(x.strip() for x in self.layouts.split(",") if x.strip())

    def limits(self) -> Limits:
        """The protocol limits this server announces in ``welcome``."""
        return Limits(
            max_message_bytes=self.max_message_bytes,
            max_rate_hz=self.max_rate_hz,
            max_players=self.max_players_per_room,
            max_watch_rooms=self.max_watch_rooms,
        )

    def engine_config(self) -> EngineConfig:
        """The engine's settings: the engine's defaults, with each of this config's
        engine settings (``--samples``, ``--no-upper-ik``, ...) set as it declares."""
        return EngineConfig(
            **engine_settings({f.name: getattr(self, f.name) for f in fields(self)})
        )

    @property
    def delay_frames(self) -> int:
        """Ticks a pose lags its frame (welcome ``lookahead_frames``): ``lookahead``
        with ``delayed_emission``, else 0 (:attr:`EngineConfig.delay`)."""
        return self.lookahead if self.delayed_emission else 0

    @property
    def secret_bytes(self) -> bytes:
        return self.token_secret.encode("utf-8")

    def key_set(self) -> KeySet:
        """The token key set: ``token_secret``'s key (kid ``secret``), ``token_keys``'
        and ``token_keys_file``'s keys, read now (the shell calls this again to reload
        the file). Raises :class:`ConfigError` for a bad or empty set, never showing
        key material."""
        keys: list[Key] = []
        if self.token_secret:
            keys.append(secret_key(self.token_secret))
        if self.token_keys:
            keys += parse_key_set(self.token_keys, env_variable("token_keys")).keys.values()
        if self.token_keys_file:
            try:
                with open(self.token_keys_file, encoding="utf-8") as f:
                    text = f.read(1 << 20)
            except (OSError, UnicodeDecodeError) as exc:
                why = getattr(exc, "strerror", None) or "not UTF-8 text"
                raise ConfigError(f"token key file {self.token_keys_file}: {why}") from None
            keys += parse_key_set(text, f"token key file {self.token_keys_file}").keys.values()
        if not keys:
            raise ConfigError(
                "no token secret or key set: set POSECAST_TOKEN_SECRET, POSECAST_TOKEN_KEYS or"
                " --token-keys-file (or pass --dev to invent one)"
            )
        return KeySet.of(keys)

    @classmethod
    def from_sources(
        cls,
        env: Mapping[str, str],
        overrides: Mapping[str, Any] | None = None,
        flags: Mapping[str, str] | None = None,
    ) -> ServerConfig:
        """Defaults, then ``POSECAST_*`` from ``env``, then non-``None`` ``overrides``.

        ``flags`` maps each override the user typed to the flag as typed
        (``{"redis_url": "--redis"}``, what
        :func:`~posecast.online.config_cli.add_arguments` records), so that an
        error names the setting as it was given (:func:`setting_names`). With ``dev`` on and no
        secret anywhere, a random secret is invented (the caller prints it). Raises
        :class:`ConfigError` for any bad value.
        """
        values: dict[str, Any] = {}
        for f in fields(cls):
            raw = env.get(env_variable(f.name))
            if raw is not None and raw != "":
                values[f.name] = _parse(f, raw)
        for name, value in (overrides or {}).items():
            if value is not None:
                values[name] = value
        keyless = not any(values.get(k) for k in ("token_keys", "token_keys_file"))
        if values.get("dev") and not values.get("token_secret") and keyless:
            values["token_secret"] = new_secret()
        given = setting_names(env, overrides, flags)
        try:
            return cls(**values, sources=given)
        except TypeError as exc:  # an unknown override name: a programming error at the edge
            raise ConfigError(str(exc)) from None

    def replace(self, **changes: Any) -> ServerConfig:
        return dataclasses.replace(self, **changes)


def engine_settings(values: Mapping[str, Any]) -> dict[str, Any]:
    """:class:`EngineConfig` keyword arguments from server settings by field name, as
    each setting declares (:func:`_engine`): ``{"no_upper_ik": True, "tick_hz": 30.0}``
    gives ``{"upper_body_ik": False, "fps": 30.0}``; names that set no engine field are
    left out. The one mapping of these settings, for :meth:`ServerConfig.engine_config`
    and for ``posecast eval``, whose ``--no-*`` flags are the same switches."""
    out: dict[str, Any] = {}
    for f in fields(ServerConfig):
        target = f.metadata.get("engine")
        if target and f.name in values:
            value = values[f.name]
            out[target] = (not value) if f.metadata["off"] else value
    return out


# The ``no_*`` switches, each of which turns one of the engine's steps off (``posecast
# serve`` and ``posecast eval`` take a ``--no-*`` flag for each).
ENGINE_SWITCHES: tuple[str, ...] = tuple(
    f.name for f in fields(ServerConfig) if f.metadata.get("off")
)

# The engine's settings that the server leaves at the engine's defaults: research
# knobs (``posecast eval`` sets some) and constants of the model. A new EngineConfig
# field belongs here or gets a server setting (:func:`_engine`); a test holds this.
ENGINE_DEFAULTS_ONLY = frozenset(
    {
        "transition_frames",
        "outlier_factor",
        "outlier_baseline",
        "ik_release_frames",
        "ik_max_drift_m",
        "stale_after_frames",
        "waist_filter_hz",
        "latent_scale",
        "home_factor",
    }
)


def setting_names(
    env: Mapping[str, str],
    overrides: Mapping[str, Any] | None = None,
    flags: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """How each setting is named to the user, by field, for the sources that
    :meth:`ServerConfig.from_sources` takes (the same arguments): the flag as typed
    where one was (``--redis``; an override given without a flag by its field), else
    its ``POSECAST_*`` variable where that is set, else, left at its default, by its
    variable when only variables were given (a container), else by its flag. The
    config's errors name settings so, and so does the CLI's (``posecast serve``'s
    check of the models directory)."""
    given: dict[str, str] = {}
    for f in fields(ServerConfig):
        if env.get(env_variable(f.name)):
            given[f.name] = env_variable(f.name)
    for name, value in (overrides or {}).items():
        if value is not None:
            given[name] = (flags or {}).get(name, name)
    by_variable = bool(given) and all(x.startswith(ENV_PREFIX) for x in given.values())
    for f in fields(ServerConfig):
        if f.name not in given:
            flag = field_flags(f)
            given[f.name] = env_variable(f.name) if by_variable or not flag else flag[0]
    return given


class _Named:
    """How an error names a setting of ``cfg``: as ``sources`` says the user gave it
    (``--tick-hz``, ``POSECAST_TICK_HZ``), else by its field (``tick_hz``)."""

    def __init__(self, cfg: ServerConfig, sources: Mapping[str, str]) -> None:
        self.cfg, self.sources = cfg, sources

    def __call__(self, name: str) -> str:
        """The setting's name, ``--tick-hz``."""
        return self.sources.get(name, name)

    def value(self, name: str) -> str:
        """The setting with its value as a user writes it: ``--tick-hz nan``,
        ``POSECAST_TICK_HZ=nan``, ``tick_hz=nan``. A float is shown in full (its repr,
        ``240.0000001``; ``:g`` made it ``240``, in range), without a whole one's
        ``.0`` (``--tick-hz 500``)."""
        value = getattr(self.cfg, name)
        text = repr(value)
        if isinstance(value, float):
            text = text.removesuffix(".0")
        label = self(name)
        return f"{label} {text}" if label.startswith("-") else f"{label}={text}"


def _check(cfg: ServerConfig, n: _Named) -> None:
    """Raise :class:`ConfigError` for the first bad setting of ``cfg``, each named by
    ``n`` as the user gave it, with the range it must be in. Secrets (the token secret,
    a Redis URL's password) are never shown."""
    if cfg.token_secret and len(cfg.token_secret) < MIN_SECRET_CHARS:
        raise ConfigError(
            f"{n('token_secret')} has {len(cfg.token_secret)} characters: the token secret"
            f" must be at least {MIN_SECRET_CHARS}"
        )
    for f in fields(cfg):  # in the order of the fields, as --help lists them
        bounds = BOUNDS.get(f.name)
        value = getattr(cfg, f.name)
        if bounds is not None and not (_is_number(value) and bounds.holds(value)):
            raise ConfigError(f"{n.value(f.name)} must be in {bounds.interval()}")
    if cfg.workers != "auto" and not (
        cfg.workers.isascii() and cfg.workers.isdigit() and 1 <= int(cfg.workers) <= MAX_WORKERS
    ):
        raise ConfigError(f"{n.value('workers')} must be auto or a number, 1 to {MAX_WORKERS}")
    if cfg.backend not in BACKENDS:
        raise ConfigError(f"{n.value('backend')} unknown: one of {', '.join(BACKENDS)}")
    if cfg.log_level.upper() not in LOG_LEVELS:
        raise ConfigError(f"{n.value('log_level')} unknown: one of {', '.join(LOG_LEVELS)}")
    ttl, hb, rt = cfg.redis_node_ttl_s, cfg.redis_heartbeat_s, cfg.redis_timeout_s
    if ttl < 2 * hb:
        raise ConfigError(
            f"{n.value('redis_node_ttl_s')} must be at least twice"
            f" {n.value('redis_heartbeat_s')}: lower {n('redis_heartbeat_s')} or raise"
            f" {n('redis_node_ttl_s')}"
        )
    # The node key's refreshes reach Redis at most this far apart while every round
    # trip answers within redis_timeout_s (docs/scale-out.md, "A slow Redis"): a
    # shorter TTL lets a live node's key lapse, and other nodes reap its players.
    gap = rt + max(hb / 2 + rt, hb)
    if not ttl > gap:
        raise ConfigError(
            f"{n.value('redis_node_ttl_s')} must be above timeout + max(heartbeat / 2 +"
            f" timeout, heartbeat) = {gap:g} s, with {n.value('redis_timeout_s')} and"
            f" {n.value('redis_heartbeat_s')}: lower {n('redis_timeout_s')} or raise"
            f" {n('redis_node_ttl_s')}"
        )
    # The URL is never shown, nor any part of it, nor urllib's errors, which quote it
    # ('Port could not be cast to integer value as 's3cret''): it may carry a password.
    if cfg.redis_url and not cfg.redis_url.startswith(("redis://", "rediss://", "unix://")):
        raise ConfigError(f"{n('redis_url')} must start with redis://, rediss:// or unix://")
    try:  # a malformed URL fails here, not in the bus's endless retries
        _ = urlsplit(cfg.redis_url).port
    except ValueError:
        raise ConfigError(
            f"{n('redis_url')} is not a well-formed URL (not shown: it may hold a password):"
            " after the host, ':' takes a port number, 0 to 65535; a password goes before"
            " the host, as in redis://user:password@host:6379/0, an IPv6 host in [ ]"
        ) from None
    for name in ("node_id", "redis_prefix"):
        value = getattr(cfg, name)
        if (value or name == "redis_prefix") and not _ID.fullmatch(value):
            raise ConfigError(f"{n.value(name)} must be 1 to 64 of A-Z a-z 0-9 _ . -")
    served = cfg._layout_names()
    known = tuple(Layout)
    if not served or any(x not in known for x in served) or len(set(served)) < len(served):
        raise ConfigError(
            f"{n.value('layouts')} must be a comma-separated subset of {', '.join(known)},"
            " each once"
        )
    cfg.limits()  # anything else Limits refuses (a value that is not an int)
    cfg.key_set()  # no key, a malformed one, a private key, two with one kid


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def field_flags(f: dataclasses.Field[Any]) -> tuple[str, ...]:
    """The option's command-line flags, its own first (none for the token secret and
    key set: command lines show up in ``ps``)."""
    if f.name in NO_FLAG:
        return ()
    return ("--" + f.name.replace("_", "-"), *f.metadata["flags"])


NO_FLAG = frozenset({"token_secret", "token_keys"})  # secrets: environment only


def env_variable(name: str) -> str:
    """The option's environment variable, ``POSECAST_TICK_HZ``."""
    return ENV_PREFIX + name.upper()


def _parse(f: dataclasses.Field[Any], raw: str) -> Any:
    kind = str(f.type)
    name = env_variable(f.name)
    try:
        if kind == "bool":
            if raw.lower() in ("1", "true", "yes", "on"):
                return True
            if raw.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(raw)
        if kind == "int":
            return int(raw)
        if kind == "float":
            return float(raw)
    except ValueError:
        raise ConfigError(f"{name}={raw!r} is not a valid {kind}") from None
    return raw
