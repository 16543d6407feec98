"""Server configuration: one frozen dataclass, built once at the edge, passed down.

Every field can be set by a ``posecast serve`` flag (``--max-rate-hz``) or an
environment variable (``POSECAST_MAX_RATE_HZ``); a flag beats the environment,
which beats the default. :meth:`ServerConfig.from_sources` is the only place that
reads either; nothing below it looks at ``os.environ``. ``docs/server.md`` lists
every option (a test keeps the table in sync with this class).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any
from urllib.parse import urlsplit

from posecast.errors import ConfigError
from posecast.online.auth.tokens import new_secret
from posecast.online.engine.backend import BACKENDS, MAX_THREADS
from posecast.online.engine.config import MAX_SAMPLES
from posecast.online.engine.upper_ik import WRIST_ELBOW_SHARE
from posecast.online.protocol.messages import MAX_LOOKAHEAD_FRAMES, Limits
from posecast.tracking.layouts import Layout

ENV_PREFIX = "POSECAST_"
_ID = re.compile(r"[A-Za-z0-9_.-]{1,64}")
MIN_SECRET_CHARS = 16
MAX_SNDBUF_BYTES = 2**31 - 1  # SO_SNDBUF is a C int


def _opt(default: Any, help: str, flags: tuple[str, ...] = (), **extra: Any) -> Any:
    """A config field; ``flags`` are extra spellings of its command-line flag."""
    return field(default=default, metadata={"help": help, "flags": flags}, **extra)


@dataclass(frozen=True)
class ServerConfig:
    """Every knob of ``posecast serve``, with safe defaults (units in the names)."""

    host: str = _opt("127.0.0.1", "interface to bind (0.0.0.0 for all)")
    port: int = _opt(8765, "TCP port for WebSocket and HTTP (0: pick a free one)")
    token_secret: str = _opt("", "HMAC-SHA256 key shared with the game backend", repr=False)
    dev: bool = _opt(False, "development mode: invent and print a secret if none is set")
    token_leeway_s: float = _opt(5.0, "clock skew allowed on token iat/exp, seconds")
    replay_cache: int = _opt(100_000, "ended-session token ids remembered (replay guard)")
    tick_hz: float = _opt(60.0, "engine ticks per second (the shipped model runs at 60)")
    samples: int = _opt(100, "latent samples per player, N")
    lookahead: int = _opt(10, "look-ahead tau in frames; poses lag frames by tau ticks")
    no_upper_ik: bool = _opt(
        False,
        "stream the poses without the upper-body pass (head on the headset, hands on the "
        "controllers): about twice the players per node, hands where the network puts them",
    )
    no_floor_ik: bool = _opt(
        False,
        "stream the feet where the network and the contact IK put them, below the floor "
        "(y = 0) included, instead of lifting them onto it",
    )
    no_swing_clearance: bool = _opt(
        False,
        "lift only feet that are below the floor, not a toe that moves over it to the "
        "height real toes keep at its speed (the swing clearance)",
    )
    no_knee_hinge: bool = _opt(
        False,
        "stream the knees as the network and the leg passes bend them, partly sideways "
        "included, instead of turning thigh and shin so each knee bends as a hinge",
    )
    no_elbow_hinge: bool = _opt(
        False,
        "stream the elbows as the upper-body pass bends them, twisted about the upper arm "
        "included, instead of turning upper arm and forearm so each elbow bends as a hinge",
    )
    wrist_elbow: float = _opt(
        WRIST_ELBOW_SHARE,
        "share of each shown elbow's placement taken from its controller's rotation (a "
        "straight wrist), the rest from the network's elbow; 0 for the network's alone",
    )
    no_hand_reach: bool = _opt(
        False,
        "leave a guessed pelvis (a headset-only player, a tracker set without a waist) "
        "where the headset puts it, after the feet are planted, instead of moving it "
        "beforehand, horizontally toward a controller beyond the arm's reach too",
    )
    no_torso_span: bool = _opt(
        False,
        "leave a guessed body (a headset-only player, a tracker set without a waist) "
        "where the reach put it, the spine chain folding or stretching to the headset, "
        "instead of moving it along the line to the headset until the network's torso "
        "spans the distance",
    )
    no_legs_apart: bool = _opt(
        False,
        "let the contact IK hold a planted foot where the other leg swings through it, "
        "instead of letting that foot give way toward the network's own just as far as "
        "keeps the legs apart",
    )
    no_pelvis_lean: bool = _opt(
        False,
        "leave a guessed pelvis (a headset-only player, a tracker set without a waist) "
        "as the network turned it instead of leaning it so that the line to the head "
        "points at the headset, before the feet are planted",
    )
    no_floor_select: bool = _opt(
        False,
        "let SSI move to a sample with a foot deeper below the floor than the floor pass "
        "lifts (0.4 m), and stay on one, instead of leaving such samples out of the pool",
    )
    no_pelvis_smoothing: bool = _opt(
        False,
        "stream each pose on its own frame's pelvis instead of the 1-2-1 average with "
        "the frames either side (which takes the pelvis's shake out of the legs)",
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

    def __post_init__(self) -> None:
        if not self.token_secret:
            raise ConfigError(
                "no token secret: set POSECAST_TOKEN_SECRET (or pass --dev to invent one)"
            )
        if len(self.token_secret) < MIN_SECRET_CHARS:
            raise ConfigError(f"the token secret must be at least {MIN_SECRET_CHARS} characters")
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"port {self.port} outside [0, 65535]")
        if not 1.0 <= self.tick_hz <= 240.0:
            raise ConfigError("tick_hz must be in [1, 240]")
        positive = (
            "samples engine_threads rate_burst max_rooms max_connections conn_per_ip_per_min "
            "sockets_per_ip fatal_per_ip_per_min reliable_queue replay_cache "
            "max_watchers_per_room frame_queue"
        )
        for name in positive.split():
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1")
        seconds = (
            "token_leeway_s control_rate_hz error_rate_hz accepts_per_s slow_consumer_s "
            "hello_timeout_s idle_timeout_s drain_timeout_s close_timeout_s redis_heartbeat_s "
            "redis_timeout_s redis_backoff_max_s"
        )
        for name in seconds.split():
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0")
        if self.engine_threads > MAX_THREADS:
            raise ConfigError(f"engine_threads must be <= {MAX_THREADS}")
        if not 0 <= self.socket_sndbuf_bytes <= MAX_SNDBUF_BYTES:
            raise ConfigError(f"socket_sndbuf_bytes must be in [0, {MAX_SNDBUF_BYTES}]")
        if not 0.0 <= self.wrist_elbow <= 1.0:
            raise ConfigError("wrist_elbow must be a share between 0 and 1")
        if self.samples > MAX_SAMPLES:
            raise ConfigError(f"samples must be <= {MAX_SAMPLES}")
        if not 0 <= self.lookahead <= MAX_LOOKAHEAD_FRAMES:  # welcome.lookahead_frames
            raise ConfigError(f"lookahead must be in [0, {MAX_LOOKAHEAD_FRAMES}] frames")
        if self.backend not in BACKENDS:
            raise ConfigError(f"backend {self.backend!r} unknown: one of {', '.join(BACKENDS)}")
        if self.log_level.upper() not in ("DEBUG", "INFO", "WARNING", "ERROR"):
            raise ConfigError(f"log_level {self.log_level!r} unknown")
        if not math.isfinite(self.redis_node_ttl_s):
            raise ConfigError("redis_node_ttl_s must be a finite number of seconds")
        if self.redis_node_ttl_s < 2 * self.redis_heartbeat_s:
            raise ConfigError("redis_node_ttl_s must be at least twice redis_heartbeat_s")
        # The node key's refreshes reach Redis at most this far apart while every round
        # trip answers within redis_timeout_s (docs/scale-out.md, "A slow Redis"): a
        # shorter TTL lets a live node's key lapse, and other nodes reap its players.
        hb, rt = self.redis_heartbeat_s, self.redis_timeout_s
        gap = rt + max(hb / 2 + rt, hb)
        if not self.redis_node_ttl_s > gap:
            raise ConfigError(
                f"redis_node_ttl_s ({self.redis_node_ttl_s:g} s) must be above redis_timeout_s"
                f" + max(redis_heartbeat_s / 2 + redis_timeout_s, redis_heartbeat_s) ="
                f" {gap:g} s: lower redis_timeout_s or raise redis_node_ttl_s"
            )
        if self.redis_url and not self.redis_url.startswith(("redis://", "rediss://", "unix://")):
            raise ConfigError("redis_url must start with redis://, rediss:// or unix://")
        try:  # a port that is not a number fails here, not in the bus's endless retries
            _ = urlsplit(self.redis_url).port
        except ValueError as exc:
            raise ConfigError(f"redis_url: {exc}") from None
        if not _ID.fullmatch(self.node_id or "x") or not _ID.fullmatch(self.redis_prefix):
            raise ConfigError("node_id and redis_prefix: 1 to 64 of A-Z a-z 0-9 _ . -")
        served = self._layout_names()
        known = tuple(Layout)
        if not served or any(x not in known for x in served) or len(set(served)) < len(served):
            raise ConfigError(f"layouts: a comma-separated subset of {', '.join(known)}")
        self.limits()  # the protocol ranges (message size, rate, room size) hold

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

    @property
    def secret_bytes(self) -> bytes:
        return self.token_secret.encode("utf-8")

    @classmethod
    def from_sources(
        cls, env: Mapping[str, str], overrides: Mapping[str, Any] | None = None
    ) -> ServerConfig:
        """Defaults, then ``POSECAST_*`` from ``env``, then non-``None`` ``overrides``.

        With ``dev`` on and no secret anywhere, a random secret is invented (the
        caller prints it). Raises :class:`ConfigError` for any bad value.
        """
        values: dict[str, Any] = {}
        for f in fields(cls):
            raw = env.get(ENV_PREFIX + f.name.upper())
            if raw is not None and raw != "":
                values[f.name] = _parse(f, raw)
        for name, value in (overrides or {}).items():
            if value is not None:
                values[name] = value
        if values.get("dev") and not values.get("token_secret"):
            values["token_secret"] = new_secret()
        try:
            return cls(**values)
        except TypeError as exc:  # an unknown override name: a programming error at the edge
            raise ConfigError(str(exc)) from None

    def replace(self, **changes: Any) -> ServerConfig:
        return dataclasses.replace(self, **changes)


# POSECAST_* variables that are read elsewhere, not server settings: the SDK tools'
# (posecast-sim, posecast-record), the native kernels' ISA override, the tests'.
OTHER_VARIABLES = frozenset(
    {"POSECAST_URL", "POSECAST_TOKEN", "POSECAST_BIN", "POSECAST_NATIVE_ISA"}
)


def unknown_variables(env: Mapping[str, str]) -> dict[str, str | None]:
    """``POSECAST_*`` names in ``env`` that set nothing, each with the setting it most
    likely meant (or ``None``): a typo, or ``POSECAST_REDIS`` for ``POSECAST_REDIS_URL``,
    would otherwise leave its default in force without a word."""
    import difflib

    known = [f.name.upper() for f in fields(ServerConfig)]

    def meant(name: str) -> str | None:  # compared without the prefix they all share
        close = difflib.get_close_matches(name[len(ENV_PREFIX) :], known, n=1, cutoff=0.7)
        return ENV_PREFIX + close[0] if close else None

    return {
        name: meant(name)
        for name in sorted(env)
        if name.startswith(ENV_PREFIX)
        and name[len(ENV_PREFIX) :] not in known
        and name not in OTHER_VARIABLES
        and not name.startswith("POSECAST_FUZZ_")
    }


def option_help() -> list[tuple[str, str, str, str]]:
    """``(field, env var, default, help)`` of every option, for the CLI and the docs."""
    out = []
    for f in fields(ServerConfig):
        if f.name == "token_secret":
            default = ""
        else:
            default = f.default if isinstance(f.default, str) else repr(f.default)
        out.append((f.name, ENV_PREFIX + f.name.upper(), default, str(f.metadata["help"])))
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``--flag`` per option (default ``None``: the environment or the default
    decides). The token secret has no flag: command lines show up in ``ps``."""
    for f in fields(ServerConfig):
        if f.name == "token_secret":
            continue
        flags = ("--" + f.name.replace("_", "-"), *f.metadata["flags"])
        text = f"{f.metadata['help']} [{ENV_PREFIX}{f.name.upper()}, default {f.default!r}]"
        if str(f.type) == "bool":
            parser.add_argument(*flags, action="store_true", default=None, help=text)
        else:
            kind = {"int": int, "float": float}.get(str(f.type), str)
            parser.add_argument(*flags, type=kind, default=None, help=text, metavar="V")


def _parse(f: dataclasses.Field[Any], raw: str) -> Any:
    kind = str(f.type)
    name = ENV_PREFIX + f.name.upper()
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
