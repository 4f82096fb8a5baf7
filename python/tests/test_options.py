"""The keyword arguments of harmap.run and of the stage functions are the command
line's flags, with the same defaults: read from the parser itself (`harmap flags`, a
hidden command that prints every flag with its default), so they cannot drift."""

import inspect
import json

import harmap
from conftest import cli

# Parameters that are not flags: the shape and the run directory (the command's INPUT,
# RUN and -o), and the progress bars (the command's global --progress).
NOT_FLAGS = {"shape", "out", "run", "progress"}
# The command's --output is the function's `out`.
RENAMED = {"output": "out"}


def same_default(name, py, cli_default, switch):
    if switch:
        return py is False
    if cli_default is None:
        return py is None
    if py is None:
        return False
    if name == "checkpoint_every":
        return harmap._duration(py) == float(cli_default)
    if isinstance(py, str):
        return py == cli_default
    return float(py) == float(cli_default)


def test_keyword_arguments_are_the_commands_flags_with_the_same_defaults():
    flags = json.loads(cli("flags").stdout)
    for command in ["run", "voxelize", "solve", "trace", "map"]:
        fn = getattr(harmap, command)
        params = {
            n: p.default
            for n, p in inspect.signature(fn).parameters.items()
            if p.kind is inspect.Parameter.KEYWORD_ONLY and n not in NOT_FLAGS
        }
        wanted = {}
        for flag, spec in flags[command].items():
            name = RENAMED.get(flag, flag).replace("-", "_")
            if name in NOT_FLAGS:
                continue
            wanted[name] = spec
        missing = sorted(set(wanted) - set(params))
        extra = sorted(set(params) - set(wanted))
        assert not missing, f"harmap.{command} lacks the command's {missing}"
        assert not extra, f"harmap.{command} takes {extra}, which the command does not"
        for name, spec in wanted.items():
            assert same_default(name, params[name], spec["default"], spec["switch"]), (
                f"harmap.{command}({name}={params[name]!r}): the command's default is "
                f"{spec['default']!r}"
            )
