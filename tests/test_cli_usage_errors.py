"""Every usage error of ``ilcpmac`` and each of its commands (an unknown command or option, a missing argument, a
value its option does not take) is one line ``error: ...`` naming it and the ``--help`` that says more, exit 2;
``--help`` itself is unchanged."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from ilcpmac.cli import main

COMMANDS = sorted(main.commands)


def one_line(args: list[str]) -> str:
    """The one line ``ilcpmac ARGS`` prints, asserting that it is one ``error:`` line on stderr and exit 2."""
    done = CliRunner().invoke(main, args, prog_name="ilcpmac")
    assert done.exit_code == 2, done.output
    assert done.stdout == "" and len(done.stderr.splitlines()) == 1, done.output
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: "), line
    return line


def typed_options(command: click.Command) -> list[click.Option]:
    """The options of ``command`` that take a number or a choice."""
    return [p for p in command.params if isinstance(p, click.Option) and not p.is_flag
            and isinstance(p.type, click.types.IntParamType | click.types.FloatParamType | click.Choice)]


@pytest.mark.parametrize("command", COMMANDS)
def test_an_unknown_option_is_one_line(command):
    assert one_line([command, "--no-such-option"]) == (
        f"error: no such option '--no-such-option' (see ilcpmac {command} --help)")


def required_argument(command: click.Command) -> click.Argument | None:
    return next((p for p in command.params if isinstance(p, click.Argument) and p.required), None)


@pytest.mark.parametrize("command", [c for c in COMMANDS if required_argument(main.commands[c]) is not None])
def test_a_missing_argument_is_one_line(command):
    argument = required_argument(main.commands[command])
    name = argument.make_metavar(click.Context(main.commands[command]))
    assert one_line([command]) == f"error: missing argument '{name}' (see ilcpmac {command} --help)"


@pytest.mark.parametrize("command, option", [(c, o.opts[0]) for c in COMMANDS for o in typed_options(main.commands[c])])
def test_a_value_an_option_does_not_take_is_one_line_naming_it(command, option):
    line = one_line([command, option, "x!"])
    assert line.startswith(f"error: invalid value for '{option}': 'x!' ") and \
        line.endswith(f" (see ilcpmac {command} --help)"), line


def test_every_command_has_an_option_of_a_typed_value_or_an_argument_tested():
    assert {"run", "export", "simulate", "identify", "sweep", "emulate"} <= {
        c for c in COMMANDS if typed_options(main.commands[c])}


def test_usage_errors_of_the_group_are_one_line():
    assert one_line(["nosuchcommand"]) == "error: no such command 'nosuchcommand' (see ilcpmac --help)"
    assert one_line(["--no-such-option"]) == "error: no such option '--no-such-option' (see ilcpmac --help)"
    assert one_line(["run", "--trials", "x"]) == (
        "error: invalid value for '--trials': 'x' is not a valid integer range (see ilcpmac run --help)")
    assert one_line(["run", "--seed", "-1"]) == (
        "error: invalid value for '--seed': -1 is not in the range x>=0 (see ilcpmac run --help)")


@pytest.mark.parametrize("args", [["--help"], ["run", "--help"], ["export", "--help"], []])
def test_help_is_as_click_writes_it(args):
    done = CliRunner().invoke(main, args, prog_name="ilcpmac")
    assert done.output.startswith("Usage: ilcpmac") and "Options:" in done.output and "error:" not in done.output
    assert done.exit_code == (0 if args else 2)
