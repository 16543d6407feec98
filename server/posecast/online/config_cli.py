"""The command line's and the environment's face of :class:`ServerConfig`: one
``--flag`` per field (:func:`add_arguments`), the options table for the CLI and the
docs (:func:`option_help`), and the ``POSECAST_*`` names that set nothing
(:func:`unknown_variables`). What the flags and variables mean is
:mod:`posecast.online.config`'s; this module only lists and parses them.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from posecast.online.config import (
    BOUNDS,
    ENV_PREFIX,
    NO_FLAG,
    ServerConfig,
    env_variable,
    field_flags,
)

# POSECAST_* variables that are read elsewhere, not server settings: the SDK tools'
# (posecast-sim, posecast-record), the native kernels' ISA and precision overrides,
# the tests'.
OTHER_VARIABLES = frozenset(
    {
        "POSECAST_URL",
        "POSECAST_TOKEN",
        "POSECAST_BIN",
        "POSECAST_NATIVE_ISA",
        "POSECAST_NATIVE_PRECISION",
    }
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
        if f.name in NO_FLAG:
            default = ""
        else:
            default = f.default if isinstance(f.default, str) else repr(f.default)
        out.append((f.name, ENV_PREFIX + f.name.upper(), default, str(f.metadata["help"])))
    return out


# The attribute of the parsed namespace where add_arguments' flags record how they were
# typed: {field: flag}, for ServerConfig.from_sources's flags (absent if none was).
FLAGS_GIVEN = "config_flags_given"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``--flag`` per option (default ``None``: the environment or the default
    decides). The token secret has no flag: command lines show up in ``ps``. Each
    flag typed is recorded in ``args.<FLAGS_GIVEN>`` as typed (``--redis`` or
    ``--redis-url``), for the errors of :meth:`ServerConfig.from_sources`."""
    for f in fields(ServerConfig):
        flags = field_flags(f)
        if not flags:
            continue
        bounds = BOUNDS.get(f.name)
        span = f", {bounds.words()}" if bounds else ""
        text = f"{f.metadata['help']} [{env_variable(f.name)}, default {f.default!r}{span}]"
        if str(f.type) == "bool":
            parser.add_argument(*flags, action=_Flag, nargs=0, const=True, default=None, help=text)
        else:
            kind = {"int": int, "float": float}.get(str(f.type), str)
            parser.add_argument(
                *flags, action=_Flag, type=kind, default=None, help=text, metavar="V"
            )


class _Flag(argparse.Action):
    """``store`` (``store_true`` with ``nargs=0``) that also records the flag as typed."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)
        given = dict(getattr(namespace, FLAGS_GIVEN, None) or {})
        given[self.dest] = option_string or self.option_strings[0]
        setattr(namespace, FLAGS_GIVEN, given)
