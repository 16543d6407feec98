"""What argparse refuses, as the CLI reports it, and ``--help`` (posecast.cli.parser)."""

from __future__ import annotations

import pytest

from posecast.cli import main
from tests.cli.conftest import user_error


@pytest.mark.parametrize(
    ("argv", "says", "hint"),
    [
        (["serve", "--port", "abc"], "invalid int value: 'abc'", "see `posecast serve --help`"),
        (
            ["data", "prepare", "--bvh", "x"],
            "required: --out",
            "see `posecast data prepare --help`",
        ),
        (
            ["eval", "--data", "d", "--samples"],
            "expected one argument",
            "see `posecast eval --help`",
        ),
        (
            ["token", "--room", "R", "--player", "P", "--ttl", "1e3"],
            "invalid int value: '1e3'",
            "see `posecast token --help`",
        ),
        (["train", "cvea"], "invalid choice: 'cvea'", "see `posecast train --help`"),
    ],
)
def test_a_command_line_mistake_is_a_config_error_naming_its_command(
    capsys, argv: list[str], says: str, hint: str
) -> None:
    """What argparse refuses (a malformed or missing value, a missing option) prints
    the CLI's own error, code and a hint naming the command's help, never a bare
    argparse message."""
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert says in err, err
    assert f"hint: {hint} for the options" in err, err


@pytest.mark.parametrize(
    ("argv", "says", "hint"),
    [
        # An unknown option with no command: it, not the missing command, is the mistake.
        (["--bogus"], "unknown option --bogus", "see `posecast --help` for the options"),
        (["-x"], "unknown option -x", "see `posecast --help` for the options"),
        (["data", "--bogus"], "unknown option --bogus", "see `posecast data --help`"),
        # ... nor is a required option it hides, perhaps by a typo of it.
        (
            ["token", "--room", "R", "--plyer", "P"],
            "unknown option --plyer",
            "did you mean --player? see `posecast token --help` for the options",
        ),
        (
            ["data", "clearance", "--bvh", "x"],  # was: "required: --data"
            "unknown option --bvh",
            "see `posecast data clearance --help` for the options",
        ),
        # After a command, by argparse's order already, now with the nearest option.
        (
            ["serve", "--no-such-flag"],
            "unknown option --no-such-flag",
            "see `posecast serve --help`",
        ),
        (
            ["serve", "--prot", "1"],
            "unknown option --prot",
            "did you mean --port? see `posecast serve --help` for the options",
        ),
        (["serve", "-p", "80"], "unknown option -p", "see `posecast serve --help` for the options"),
        (["--bogus", "serve"], "unknown option --bogus", "see `posecast serve --help`"),
        # An option typed before its command.
        (
            ["--port", "80", "serve"],
            "unknown option --port",
            "an option goes after its command: `posecast serve --port`",
        ),
        # A misspelt or missing command: named with the commands, not by argparse's dest.
        (
            ["srve"],
            "unknown command 'srve' for `posecast` (one of data, train,",
            "did you mean `posecast serve`? see `posecast --help` for the commands",
        ),
        (
            ["data", "prep", "--out", "x"],
            "unknown command 'prep' for `posecast data` (one of prepare, clearance, wrists)",
            "did you mean `posecast data prepare`? see `posecast data --help` for the commands",
        ),
        ([], "`posecast` needs a command: data, train,", "see `posecast --help` for the commands"),
        (
            ["data"],
            "`posecast data` needs a command: prepare, clearance, wrists",
            "see `posecast data --help` for the commands",
        ),
        (["serve", "80"], "unrecognized arguments: 80", "see `posecast serve --help`"),
    ],
)
def test_the_first_wrong_word_is_the_one_reported(
    capsys, argv: list[str], says: str, hint: str
) -> None:
    """argparse finds a missing command or option before it looks at the words it did
    not know: ``posecast --bogus`` said a command was missing. The CLI names the
    unknown option or command, in the order typed, with the nearest valid one."""
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {says}" in err, err
    assert f"hint: {hint}" in err, err
    assert "did you mean" in hint or "did you mean" not in err, err


@pytest.mark.parametrize(
    ("argv", "says", "hint"),
    [
        (
            ["token", "--room", "R", "--player", "P", "--secret", "-SuperSecretValue123456"],
            "argument --secret: expected one argument",
            "a value that starts with '-' goes after '=' (--secret=VALUE)",
        ),
        (
            ["token", "--room", "R", "--player", "P", "--sec", "-SuperSecretValue123456"],
            "argument --secret: expected one argument",
            "(--secret=VALUE)",
        ),
        (
            ["token", "--room", "R", "--player", "P", "--secret", "-hSuperSecretValue123456"],
            "argument --secret: expected one argument",
            "(--secret=VALUE)",
        ),
        (
            ["token", "--room", "R", "--player", "-bob"],
            "argument --player: expected one argument",
            "(--player=VALUE)",
        ),
        (
            ["serve", "--redis", "-SuperSecretValue123456"],
            "argument --redis-url/--redis: expected one argument",
            "(--redis=VALUE)",
        ),
        (
            ["serve", "--re=redis://:SuperSecretValue123456@h/0"],
            "ambiguous option: --re=<hidden> could match",
            "see `posecast serve --help` for the options",
        ),
    ],
)
def test_a_value_that_starts_with_a_dash_is_not_an_unknown_option(
    capsys, argv: list[str], says: str, hint: str
) -> None:
    """The word after an option that takes a value is its value, not an option: the
    CLI called ``--secret -SuperSecret...`` an unknown option, and so printed the
    secret on stderr. argparse's own complaint is reported, with the ``--opt=VALUE``
    form that takes such a value, and a secret's value is never shown."""
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {says}" in err, err
    assert "hint: " in err and hint in err.split("hint: ", 1)[1], err
    assert "SuperSecretValue123456" not in err and "unknown option" not in err, err


def test_a_value_that_starts_with_a_dash_goes_after_an_equals_sign(capsys) -> None:
    argv = ["token", "--room", "R", "--player", "P", "--secret=-SuperSecretValue123456-0123456789"]
    assert main(argv) == 0
    assert capsys.readouterr().out.count(".") == 2  # a JWT: header.claims.signature


def test_help_describes_posecast_for_its_users(capsys) -> None:
    """``posecast --help`` showed the module docstring's developer note ("Configuration
    is parsed here, once, and passed down.")."""
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0
    assert "Configuration is parsed" not in out
    assert "Full-body poses for VR players" in " ".join(out.split()), out
    assert "posecast serve --dev" in " ".join(out.split()), out
