"""The ``posecast`` command line's parser: :func:`build_parser` gathers each command
module's parsers (:mod:`posecast.cli.data`, ...) under one :class:`Parser`, whose
refusals are the CLI's errors (``posecast: error [CONFIG_INVALID]: ...`` and a hint)
rather than argparse's."""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import re
import sys
from collections.abc import Iterator, Sequence
from typing import NoReturn

from posecast.cli import bench, data, evaluate, serve, train
from posecast.cli.common import config_error
from posecast.errors import ConfigError

_NEGATIVE_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+$")  # a value to argparse, not an option


class Parser(argparse.ArgumentParser):
    """argparse whose refusals (an unknown option, a missing or malformed value, no
    command) print the usage and raise a :class:`ConfigError` hinted with the
    command's ``--help``, which :func:`posecast.cli.main` prints as every other user error.
    Subcommand parsers are made of this class too (argparse's ``add_subparsers`` takes
    the parent's class).

    The first wrong word of a command is the one reported (:meth:`refusal`): argparse
    finds a missing argument or command before it looks at the words it did not
    know, so ``posecast --bogus`` said a command was missing and
    ``posecast token --room R --plyer P`` that ``--player`` was. An unknown option or
    command is named with the nearest valid one."""

    _argv: Sequence[str] = ()  # the words this parser was last given (its command's own)

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        self._argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(self._argv, namespace)

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        raise self.refusal(self._argv, message)

    def refusal(self, argv: Sequence[str], message: str) -> ConfigError:
        """The error for ``argv`` (this command's words), which argparse refused with
        ``message``: an unknown option or command, in the order typed, else a missing
        command, else ``message``."""
        commands = self.commands()
        hidden: list[str] = []  # the values of secret options: never shown
        dashed = ""  # an option whose value starts with '-' (argparse takes it for one)
        value_next = False
        for i, arg in enumerate(argv):
            if value_next:  # the value of the option before it, whatever it looks like
                value_next = False
                continue
            if arg == "--":  # every word after it is a value (the first one a command)
                rest = argv[i + 1 : i + 2]
                if commands and rest and rest[0] not in commands:
                    return self._unknown_command(rest[0], commands)
                break
            if _is_option(arg):
                if not self._knows(arg):
                    return self._unknown_option(arg.split("=", 1)[0])
                actions = self._actions_of(arg)
                secret = any(a.dest in _secret_dests() for a in actions)
                attached = _attached_value(arg, actions)
                if attached is not None:  # --opt=V, -xV
                    if secret:
                        hidden.append(attached)
                elif any(a.nargs != 0 for a in actions) and i + 1 < len(argv):
                    word = argv[i + 1]
                    if secret:
                        hidden.append(word)
                    if _is_option(word):
                        dashed = dashed or _typed_option(arg, actions)
                    if word != "--" and not (_is_option(word) and self._knows(word)):
                        value_next = True
            elif commands:
                if arg not in commands:
                    return self._unknown_command(arg, commands)
                return commands[arg].refusal(argv[i + 1 :], message)  # the rest are its
        else:
            if commands:
                return config_error(
                    f"`{self.prog}` needs a command: {', '.join(commands)}",
                    f"see `{self.prog} --help` for the commands",
                )
        message = _redact(message, hidden)
        if dashed and "expected one argument" in message:
            return config_error(
                message,
                f"a value that starts with '-' goes after '=' ({dashed}=VALUE); "
                f"see `{self.prog} --help` for the options",
            )
        return _usage_error(self.prog, message)

    def commands(self) -> dict[str, Parser]:
        """This command's subcommands (none for a leaf)."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                return dict(action.choices)
        return {}

    def options(self) -> list[str]:
        return [s for action in self._actions for s in action.option_strings]

    def _knows(self, arg: str) -> bool:
        name = arg.split("=", 1)[0]
        options = self.options()
        if name in options:
            return True
        if name.startswith("--"):  # an abbreviation, as argparse takes (or refuses) it
            return self.allow_abbrev and any(o.startswith(name) for o in options)
        return arg[:2] in options  # -vq, -xVALUE

    def _actions_of(self, arg: str) -> list[argparse.Action]:
        """The options ``arg`` (one :meth:`_knows`) may stand for: one, or those an
        abbreviation matches."""
        name = arg.split("=", 1)[0]
        exact = [a for a in self._actions if name in a.option_strings]
        if exact:
            return exact
        if name.startswith("--"):
            return [a for a in self._actions if any(o.startswith(name) for o in a.option_strings)]
        return [a for a in self._actions if arg[:2] in a.option_strings]

    def _unknown_option(self, name: str) -> ConfigError:
        # Compared without the dashes, which every option shares (--bogus is not like
        # --layouts); a long option before a short one of the same letters.
        by_name = {o.lstrip("-"): o for o in sorted(self.options(), key=len, reverse=True)}
        near = difflib.get_close_matches(name.lstrip("-"), list(by_name), n=1, cutoff=0.6)
        if near:
            hint = f"did you mean {by_name[near[0]]}? see `{self.prog} --help` for the options"
        else:
            owners = [p.prog for p in _leaves(self) if p is not self and p._knows(name)]
            if owners:  # an option typed before its command
                hint = f"an option goes after its command: `{owners[0]} {name}`"
            else:
                hint = f"see `{self.prog} --help` for the options"
        return config_error(f"unknown option {name}", hint)

    def _unknown_command(self, word: str, commands: dict[str, Parser]) -> ConfigError:
        near = difflib.get_close_matches(word, list(commands), n=1, cutoff=0.6)
        help_ = f"see `{self.prog} --help` for the commands"
        hint = f"did you mean `{self.prog} {near[0]}`? {help_}" if near else help_
        return config_error(
            f"unknown command {word!r} for `{self.prog}` (one of {', '.join(commands)})", hint
        )


def _is_option(arg: str) -> bool:
    """``arg`` is an option to argparse (``-x``, ``--name``, ``--name=V``), not a value."""
    return arg.startswith("-") and arg != "-" and not _NEGATIVE_NUMBER.match(arg) and " " not in arg


def _attached_value(arg: str, actions: Sequence[argparse.Action]) -> str | None:
    """The value typed in ``arg`` itself (``--opt=V``, ``-xV``), else ``None``."""
    if "=" in arg and arg.startswith("--"):
        return arg.split("=", 1)[1]
    if not arg.startswith("--") and len(arg) > 2 and all(a.nargs != 0 for a in actions):
        return arg[3:] if arg[2] == "=" else arg[2:]
    return None


def _typed_option(arg: str, actions: Sequence[argparse.Action]) -> str:
    """The option ``arg`` names, as typed (``--redis``), an abbreviation of one in
    full (``--sec``: ``--secret``)."""
    name = arg.split("=", 1)[0]
    spelt = [o for a in actions for o in a.option_strings if o.startswith(name)]
    return name if name in spelt or len(spelt) != 1 else spelt[0]


def _secret_dests() -> frozenset[str]:
    """The options whose values are never shown: ``token --secret`` and the server
    settings kept out of the config's repr (the token secret; a Redis URL, which may
    carry a password)."""
    from posecast.online.config import ServerConfig

    return frozenset({"secret"} | {f.name for f in dataclasses.fields(ServerConfig) if not f.repr})


def _redact(message: str, hidden: Sequence[str]) -> str:
    """``message`` with each word of ``hidden`` shown as ``<hidden>`` where it stands
    as a value: a word of its own, quoted as argparse quotes one, or after '='."""
    for word in hidden:
        if word:
            message = re.sub(
                rf"(?:^|(?<=[\s'\"=])){re.escape(word)}(?=$|[\s'\"])", "<hidden>", message
            )
    return message


def _leaves(parser: Parser) -> Iterator[Parser]:
    """``parser`` and every command under it that takes no further command."""
    commands = parser.commands()
    if not commands:
        yield parser
    for sub in commands.values():
        yield from _leaves(sub)


def parser_for(parser: Parser, command: str) -> Parser:
    """The parser of ``command`` (``"data prepare"``) under ``parser``."""
    for word in command.split():
        parser = parser.commands().get(word, parser)
    return parser


def _usage_error(prog: str, message: str) -> ConfigError:
    return config_error(message, f"see `{prog} --help` for the options")


# What ``posecast --help`` says (the module docstring is for developers).
_DESCRIPTION = (
    "Full-body poses for VR players from a headset and its controllers (with or without "
    "a waist tracker, or any tracker set), streamed live to everyone in a room; and the "
    "tools that prepare the motion data, train, export, evaluate and benchmark the models."
)
_EPILOG = (
    "Start with `posecast demo` (a server and two simulated headsets, with a live 3D viewer) or "
    "`posecast serve --dev`; `posecast COMMAND --help` gives a command's options. "
    "Docs: README.md, docs/server.md."
)


def build_parser() -> Parser:
    """``posecast`` and every command under it."""
    parser = Parser(prog="posecast", description=_DESCRIPTION, epilog=_EPILOG)
    sub = parser.add_subparsers(dest="command", required=True)
    for commands in (data, train, evaluate, bench, serve):  # in the order --help lists them
        commands.add_parsers(sub)
    return parser
