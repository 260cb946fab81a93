"""``--help`` of every command answers without the heavy imports (a test of imports, not of time),
and every option's help says its default once."""

import argparse
import json
import subprocess
import sys

import pytest

from smarts.command_line import HelpFormatter

HEAVY = ("torch", "torchrl", "stable_baselines3", "tensorboard")


def _modules_after(code: str) -> set[str]:
    """The modules imported by ``code`` run in a fresh interpreter (it prints nothing else)."""
    script = "import io, json, sys, contextlib\nwith contextlib.redirect_stdout(io.StringIO()):\n"
    script += "".join(f"    {line}\n" for line in code.splitlines())
    script += "print(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


def _help(module: str, argv: list[str]) -> str:
    return (
        f"try:\n    __import__('{module}', fromlist=['main']).main({argv!r} + ['--help'])\nexcept SystemExit:\n    pass"
    )


@pytest.mark.parametrize("module", ["train.__main__", "smarts.__main__"])
def test_the_command_list_imports_no_command(module):
    loaded = _modules_after(_help(module, []))
    assert not [m for m in loaded if m.split(".")[0] in (*HEAVY, "numba")]
    assert not [m for m in loaded if m.startswith(("train.", "smarts.")) and m not in
                (module, "smarts.command_line", "smarts.exit_codes")]  # fmt: skip


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The parsers of ``parser``'s commands, by name."""
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return {name: p for a in actions for name, p in a.choices.items()}


def _commands() -> list[tuple[str, list[str]]]:
    """(module, argv) of every command and command group of both command lines."""
    from smarts.__main__ import COMMANDS as SMARTS
    from smarts.__main__ import build_parser as smarts_parser
    from train.__main__ import COMMANDS as TRAIN

    out = [("train.__main__", [c.name]) for c in TRAIN]
    for group in SMARTS:
        out.append(("smarts.__main__", [group.name]))
        for name in _subparsers(_subparsers(smarts_parser([group.name]))[group.name]):
            out.append(("smarts.__main__", [group.name, name]))
    return out


def test_every_commands_help_imports_no_torch():
    # One interpreter runs every --help in turn and notes the heavy modules loaded after each: the
    # first command that imports one is named.
    code = "heavy = {}\n"
    for module, argv in _commands():
        code += _help(module, argv) + "\n"
        code += f"heavy[{' '.join(argv)!r}] = sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r})\n"
    code += "sys.stderr.write(json.dumps(heavy))"
    script = "import io, json, sys, contextlib\nwith contextlib.redirect_stdout(io.StringIO()):\n"
    script += "".join(f"    {line}\n" for line in code.splitlines())
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    heavy = json.loads(done.stderr.splitlines()[-1])
    assert len(heavy) == len(_commands()) >= 15
    assert {command: modules for command, modules in heavy.items() if modules} == {}


def _all_parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    from smarts.__main__ import build_parser as smarts_parser
    from train.__main__ import build_parser as train_parser

    todo = [("python -m train", train_parser()), ("smarts", smarts_parser())]
    out = []
    while todo:
        name, parser = todo.pop()
        out.append((name, parser))
        todo += [(f"{name} {sub}", p) for sub, p in _subparsers(parser).items()]
    return out


def test_every_option_says_its_default_once():
    problems = []
    for name, parser in _all_parsers():
        assert "``" not in (parser.description or "") + (parser.epilog or ""), name  # no raw markup
        formatter = HelpFormatter(name)
        for action in parser._actions:
            if not action.option_strings or action.help is argparse.SUPPRESS:
                continue
            text = formatter._expand_help(action)
            flag = f"{name} {action.option_strings[0]}"
            if text.count("(default") > 1 or "(default: None)" in text:
                problems.append(f"{flag}: {text}")
            if action.required and "(default" in text:
                problems.append(f"{flag} is required: {text}")
            shown = action.default not in (None, argparse.SUPPRESS, False, True) and action.nargs != 0
            if shown and "default" not in text.lower():
                problems.append(f"{flag}: default {action.default!r} not shown: {text}")
    assert problems == []
    helps = {name: parser for name, parser in _all_parsers()}
    assert "(default: collaborative)" in " ".join(helps["python -m train benchmark"].format_help().split())


def test_every_option_value_shows_its_type_or_choices():
    """A number or a path is named as such in the usage (``--episodes INT``); an option with
    choices lists them; the options made from a config schema say their type in their help."""
    problems = []
    for name, parser in _all_parsers():
        usage = " ".join(parser.format_usage().split())
        for action in parser._actions:
            if not action.option_strings or action.nargs == 0 or action.help is argparse.SUPPRESS:
                continue
            flag = action.option_strings[0]
            kinds = {int: "INT", float: "FLOAT"}
            if action.type in kinds and action.metavar is None and f"{flag} {kinds[action.type]}" not in usage:
                problems.append(f"{name} {flag}: {action.type.__name__} value not named in {usage}")
            if action.choices is not None and action.metavar is None and "{" not in usage:
                problems.append(f"{name} {flag}: choices not listed")
    assert problems == []
    ppo = dict(_all_parsers())["python -m train ppo"].format_help()
    assert "(int; default:" in ppo and "(float; default:" in ppo
