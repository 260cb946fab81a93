"""What every command line of the project shares (``smarts ...``, ``python -m train ...``): one help
format, and commands whose modules are imported only when they run or show their own help.

``--help`` must answer at once, so a top-level parser lists its commands from a table of names and
one-line helps (``Command``) and imports the module that adds a command's options only for the
command named on the command line (``add_commands``); the heavy imports (torch, the simulator)
live inside the functions that run a command.
"""

from __future__ import annotations

import argparse
import importlib
import re
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

_DEFAULT_SAID = re.compile(r"default", re.IGNORECASE)
_TYPE_NAMES = {int: "INT", float: "FLOAT", Path: "PATH"}


class HelpFormatter(argparse.HelpFormatter):
    """Every option's default once, at the end of its help: ``(default: X)`` is added unless the
    help already says its default, the option is required, takes no value (a flag) or has none
    (``None``). Descriptions and epilogs are wrapped paragraph by paragraph; a paragraph whose
    lines are indented (examples) is kept as written."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if isinstance(action, argparse.BooleanOptionalAction) and isinstance(action.default, bool):
            if _DEFAULT_SAID.search(text):
                return text
            on, off = action.option_strings[0], action.option_strings[-1]
            return f"{text} (default: {on if action.default else off})"
        if (
            "%(default)" in text
            or _DEFAULT_SAID.search(text)
            or action.required
            or action.nargs == 0
            or action.default is None
            or action.default is argparse.SUPPRESS
            or not action.option_strings
        ):
            return text
        return text + " (default: %(default)s)"

    def _get_default_metavar_for_optional(self, action: argparse.Action) -> str:
        """An option's value named by its type where that says more than its name (``--episodes
        INT``, ``--lr FLOAT``, ``--out PATH``); text values keep their name (``--agent AGENT``)."""
        kind = _TYPE_NAMES.get(action.type)
        return kind if kind is not None else super()._get_default_metavar_for_optional(action)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        paragraphs = re.split(r"\n\s*\n", text.strip("\n"))
        out = []
        for paragraph in paragraphs:
            lines = paragraph.splitlines()
            if any(line[:1].isspace() for line in lines):  # examples: as written
                out.append("\n".join(indent + line for line in lines))
            else:
                out.append(textwrap.fill(" ".join(line.strip() for line in lines), width,
                                         initial_indent=indent, subsequent_indent=indent))  # fmt: skip
        return "\n\n".join(out)


@dataclass(frozen=True)
class Command:
    """One command of a command line: its name, its one-line help, and ``options``: adds the
    command's arguments and ``set_defaults(run=...)`` to its parser, given the command line (a
    function, or ``"module:function"``, imported only when the command is used)."""

    name: str
    help: str
    options: Callable[[argparse.ArgumentParser, Sequence[str] | None], None] | str


def add_commands(
    sub: argparse._SubParsersAction, commands: Sequence[Command], argv: Sequence[str] | None
) -> dict[str, argparse.ArgumentParser]:
    """A parser per command (``HelpFormatter``), with the options of the command that ``argv``
    names (its first word that is not an option); ``argv`` None: of every command (a complete
    parser, slower)."""
    named = next((word for word in argv if not word.startswith("-")), None) if argv is not None else None
    parsers = {}
    for command in commands:
        parser = sub.add_parser(command.name, help=command.help, description=_sentence(command.help),
                                formatter_class=HelpFormatter)  # fmt: skip
        if argv is None or command.name == named:
            options = command.options
            if isinstance(options, str):
                module, function = options.split(":")
                options = getattr(importlib.import_module(module), function)
            options(parser, argv)
        parsers[command.name] = parser
    return parsers


def _sentence(text: str) -> str:
    """A one-line help as a sentence: capitalised, with a full stop."""
    text = text[:1].upper() + text[1:]
    return text if text.endswith((".", "!", "?")) else text + "."
