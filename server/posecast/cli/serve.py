"""The live service: ``posecast serve`` (the pose-streaming server,
:mod:`posecast.online.shell.app`, its configuration :mod:`posecast.online.config`,
``docs/server.md``), ``posecast token`` (a development join token,
:mod:`posecast.online.auth.tokens`), ``posecast keygen`` (a token key pair,
:mod:`posecast.online.auth.keys`) and ``posecast demo`` (a server, two simulated
headsets and a spectator on loopback, :mod:`posecast.demo`; what ``make run`` does)."""

from __future__ import annotations

import argparse
import contextlib
import errno
import logging
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from posecast.cli.common import (
    at_least,
    check_models_dir,
    check_samples,
    config_error,
    finite,
    hinted,
    need,
)
from posecast.errors import ConfigError


@contextlib.contextmanager
def _listen_errors(host: str, port: int, hint: str) -> Iterator[None]:
    """Turn a socket that cannot be bound (port in use, unknown host) into a ConfigError."""
    try:
        yield
    except OSError as exc:
        bind = (errno.EADDRINUSE, errno.EADDRNOTAVAIL, errno.EACCES)
        if not isinstance(exc, socket.gaierror) and exc.errno not in bind:
            raise
        raise config_error(f"cannot listen on {host}:{port}: {exc.strerror or exc}", hint) from None


def cmd_serve(args: argparse.Namespace) -> int:
    import asyncio
    import os

    from posecast.online.config import MIN_SECRET_CHARS, ServerConfig, setting_names
    from posecast.online.config_cli import FLAGS_GIVEN, unknown_variables
    from posecast.online.shell.app import serve_until_signal
    from posecast.online.shell.logging import configure

    flags: dict[str, str] = getattr(args, FLAGS_GIVEN, None) or {}
    skip = ("command", "func", FLAGS_GIVEN)
    overrides = {k: v for k, v in vars(args).items() if k not in skip}
    try:  # an error names each setting as typed: its flag, else its POSECAST_* variable
        cfg = ServerConfig.from_sources(os.environ, overrides, flags)
    except ConfigError as exc:
        if "token secret" in exc.message:
            hint = (
                f"export POSECAST_TOKEN_SECRET=<{MIN_SECRET_CHARS}+ random characters, the "
                "game backend's key>, or a key set (POSECAST_TOKEN_KEYS, --token-keys-file;"
                " `posecast keygen`), or pass --dev for a throwaway one"
            )
        else:
            hint = "set it by its flag or POSECAST_* variable: see `posecast serve --help`"
        raise hinted(exc, hint + " (docs/server.md)") from None
    named = setting_names(os.environ, overrides, flags)["models_dir"]
    check_models_dir(Path(cfg.models_dir) if cfg.models_dir else None, named)
    configure(cfg.log_level)
    for name, meant in unknown_variables(os.environ).items():
        logging.getLogger("posecast.server").warning(
            "unknown setting ignored", extra={"variable": name, "did_you_mean": meant}
        )
    invented = cfg.dev and cfg.token_secret not in ("", os.environ.get("POSECAST_TOKEN_SECRET"))
    if invented:
        print(f"posecast: --dev: token secret for this run: {cfg.token_secret}", flush=True)

    def ready(port: int) -> None:
        # An IPv6 host in brackets, as a URL writes it (ws://[::]:8765, not ws://:::8765);
        # "" is every IPv4 and every IPv6 interface (ws://:8765 named neither).
        host = f"[{cfg.host}]" if ":" in cfg.host else cfg.host
        where = f"ws://{host}:{port}" if host else f"ws://0.0.0.0:{port} and ws://[::]:{port}"
        print(f"posecast: listening on {where}", flush=True)
        if cfg.dev:
            secret = cfg.token_secret if invented else None
            print("\n".join(dev_lines(cfg.host, port, secret)), flush=True)

    with _listen_errors(cfg.host, cfg.port, "pick another --port (0: any free one) or --host"):
        asyncio.run(serve_until_signal(cfg, ready))
    return 0


def dev_lines(host: str, port: int, secret: str | None) -> list[str]:
    """What ``posecast serve --dev`` prints once it listens: the viewer's URL and, for
    an invented secret, ``export`` lines to paste into a client's shell (the names the
    SDK tools and the README's snippets read). The URLs are loopback ones where the
    bind covers one (:func:`_loopback_at`): the viewer's dev tokens are handed to
    loopback clients only, so a server bound elsewhere gets no viewer line but a word
    on why."""
    import shlex

    at = _loopback_at(host)
    if at is not None:
        lines = [f"posecast: --dev: viewer at http://{at}:{port}/viewer/ (this machine only)"]
    else:
        at = f"[{host}]" if ":" in host else host
        lines = [
            f"posecast: --dev: no viewer here: its dev tokens need a loopback bind, and "
            f"host {host} is not one (--host 127.0.0.1, the default, or 0.0.0.0 is)"
        ]
    if secret is not None:
        lines += [
            "posecast: --dev: for a client in another shell, paste:",
            f"export POSECAST_TOKEN_SECRET={shlex.quote(secret)}",
            f"export POSECAST_URL=ws://{at}:{port}/",
        ]
    return lines


def _loopback_at(host: str) -> str | None:
    """The loopback address, as a URL writes it (``127.0.0.1``, ``[::1]``), at which a
    client on this machine reaches a server bound to ``host``, or ``None`` where the
    bind covers none. The server binds every address ``host`` resolves to, as asyncio
    resolves it (``''``: every interface, IPv4 and IPv6), each IPv6 one IPv6-only:
    ``::`` is reached at ``[::1]``, never at 127.0.0.1. What counts as loopback is the
    viewer routes' own rule (``shell.http.is_loopback_address``, which refuses the others)."""
    import ipaddress

    from posecast.online.shell.http import is_loopback_address

    try:
        infos = socket.getaddrinfo(
            host or None, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )
    except OSError:
        return None
    reached = []
    for *_, sockaddr in infos:
        ip = ipaddress.ip_address(str(sockaddr[0]).split("%", 1)[0])
        at = ("127.0.0.1" if ip.version == 4 else "::1") if ip.is_unspecified else str(ip)
        if is_loopback_address(at):
            reached.append(at)
    if not reached:
        return None
    at = min(reached, key=lambda a: ":" in a)  # IPv4 first
    return f"[{at}]" if ":" in at else at


def cmd_token(args: argparse.Namespace) -> int:
    import json
    import os
    import time

    from posecast.online.auth.keys import ALGORITHMS, SigningKey
    from posecast.online.auth.tokens import MAX_TTL_S, mint
    from posecast.online.config import MIN_SECRET_CHARS

    if args.key is not None:
        if args.secret:
            raise config_error("--secret and --key both given", "mint with one of them")
        try:
            jwk = json.loads(Path(args.key).read_text("utf-8"))
            key = SigningKey.from_jwk(jwk if isinstance(jwk, dict) else {})
        except OSError as exc:
            raise config_error(f"--key {args.key}: {exc.strerror or exc}", _KEY_HINT) from None
        except ValueError as exc:  # not JSON (never quoted: it is a private key), or no key
            why = str(exc) if not isinstance(exc, json.JSONDecodeError) else "not JSON"
            raise config_error(f"--key {args.key}: {why}", _KEY_HINT) from None
        except ConfigError as exc:
            raise config_error(f"--key {args.key}: {exc.message}", _KEY_HINT) from None
    else:
        secret = args.secret or os.environ.get("POSECAST_TOKEN_SECRET", "")
        if not secret:
            raise config_error(
                "no token secret or key",
                "pass --secret KEY, set POSECAST_TOKEN_SECRET (the server's key), or pass"
                " --key FILE (a private key from `posecast keygen`)",
            )
        if len(secret) < MIN_SECRET_CHARS:
            raise config_error(
                f"the token secret must be at least {MIN_SECRET_CHARS} characters",
                "use the secret the server runs with (POSECAST_TOKEN_SECRET)",
            )
        key = SigningKey.from_secret(secret, kid=None)
    if args.alg is not None and args.alg != key.alg:
        raise config_error(
            f"--alg {args.alg} does not fit the key, which signs {key.alg}",
            f"drop --alg, or mint with a {args.alg} key ({', '.join(ALGORITHMS)})",
        )
    if args.kid is not None:
        key = SigningKey(key.alg, key.material, args.kid or None)
    if not 0 < args.ttl <= MAX_TTL_S:
        raise config_error(
            f"--ttl {args.ttl} outside [1, {MAX_TTL_S}] seconds", "e.g. --ttl 3600 (one hour)"
        )
    if not args.room or not args.player:
        raise config_error(
            "--room and --player must not be empty", "e.g. --room lobby --player p-17"
        )
    rooms = tuple(r for r in (args.rooms or "").split(",") if r)
    if rooms and args.role != "backend":
        raise config_error(
            "only a backend token may list --rooms", "add --role backend or drop --rooms"
        )
    try:
        token = mint(
            key,
            room=args.room,
            player=args.player,
            role=args.role,
            ttl_s=args.ttl,
            now=time.time(),
            rooms=rooms,
        )
    except ValueError as exc:  # mint's own checks of the values above
        raise config_error(str(exc), "see `posecast token --help`") from None
    print(token)
    return 0


_KEY_HINT = "a private JWK file, as `posecast keygen --out FILE` writes"


def cmd_keygen(args: argparse.Namespace) -> int:
    """A new key: the private JWK to ``--out`` (mode 0600, for the game backend), the
    public key set to stdout (for the servers' POSECAST_TOKEN_KEYS or key file)."""
    import json
    import os

    from posecast.online.auth.keys import KID_PATTERN, generate

    if not KID_PATTERN.fullmatch(args.kid):
        raise config_error(f"--kid {args.kid!r} is not a key id", "1 to 64 of A-Z a-z 0-9 _ . : -")
    private, public = generate(args.alg, args.kid)
    try:
        fd = os.open(args.out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise config_error(
            f"--out {args.out}: {exc.strerror or exc}",
            "name a new file: keygen never overwrites a key",
        ) from None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(json.dumps(private, indent=2) + "\n")
    print(json.dumps({"keys": [public]}, indent=2))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    import asyncio

    at_least("--port", args.port, 0, "demo")
    if args.port > 65535:
        raise config_error(f"--port {args.port} outside [0, 65535]", "0 picks any free port")
    check_samples("--samples", [args.samples], "demo")
    if args.seconds is not None:
        finite("--seconds", args.seconds, "demo", positive=True)
    need("data", "scipy")
    from posecast.demo import run

    if args.bvh is not None:  # read it now: a bad file must fail before the server starts
        from posecast.offline.dataset.prepare import process_file
        from posecast.offline.motion.rig import load_rigs

        process_file(args.bvh, load_rigs())
    with (
        contextlib.suppress(KeyboardInterrupt),
        _listen_errors("127.0.0.1", args.port, "pick another --port (0: any free one)"),
    ):
        asyncio.run(run(args.port, args.seconds, args.bvh, args.samples))
    return 0


def add_parsers(sub: argparse._SubParsersAction[Any]) -> None:
    """Add ``posecast serve``, ``token``, ``keygen`` and ``demo`` to ``sub``."""
    from posecast.online.config_cli import add_arguments

    serve = sub.add_parser("serve", help="run the pose-streaming server (docs/server.md)")
    add_arguments(serve)
    serve.set_defaults(func=cmd_serve)

    tok = sub.add_parser("token", help="mint a join token, a JWT (development; the backend mints)")
    tok.add_argument("--secret", help="HS256 key (default: $POSECAST_TOKEN_SECRET)")
    tok.add_argument("--key", help="private JWK file to sign with (ES256, EdDSA or HS256)")
    tok.add_argument("--kid", help="kid in the header (default: the key's; none for --secret)")
    tok.add_argument("--alg", choices=("HS256", "ES256", "EdDSA"), help="must fit the key")
    tok.add_argument("--room", required=True, help="room the token joins")
    tok.add_argument("--player", required=True, help="player id (server-unique)")
    tok.add_argument("--role", default="player", choices=("player", "spectator", "backend"))
    tok.add_argument("--rooms", help="comma-separated extra rooms a backend may watch")
    tok.add_argument("--ttl", type=int, default=3600, help="seconds until it expires (3600)")
    tok.set_defaults(func=cmd_token)

    gen = sub.add_parser(
        "keygen", help="a new token key: private JWK to --out, public key set to stdout"
    )
    gen.add_argument(
        "--alg",
        default="ES256",
        choices=("ES256", "EdDSA", "HS256"),
        help="ES256 (default) or EdDSA: servers hold only the public key; HS256: a shared secret",
    )
    gen.add_argument("--kid", required=True, help="the key's id, e.g. 2026-12")
    gen.add_argument("--out", required=True, help="new file for the private key (mode 0600)")
    gen.set_defaults(func=cmd_keygen)

    demo = sub.add_parser("demo", help="server + two simulated headsets + a spectator (make run)")
    demo.add_argument("--port", type=int, default=8765, help="port (0: any free one)")
    demo.add_argument("--seconds", type=float, default=None, help="stop after this long")
    demo.add_argument("--bvh", type=Path, default=None, help="replay this BVH file")
    demo.add_argument("--samples", type=int, default=100, help="latent samples N")
    demo.set_defaults(func=cmd_demo)
