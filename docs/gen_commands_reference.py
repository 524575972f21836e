"""Writes the guide's reference/commands.md from fieldcal's own argparse parsers at every build
(a MkDocs hook, mkdocs.yml's `hooks:`; nothing is kept in git), so the page cannot drift from the commands.

Each command, and each subcommand of a group (`sim serve`, `registry rebuild`), gets a heading,
and argparse's own help text (usage, description, options), which is what `fieldcal COMMAND --help` prints.
Run alone (`python docs/gen_commands_reference.py`) it prints the page."""
from __future__ import annotations

import argparse
import os
import sys

PAGE = "reference/commands.md"
HELP_WIDTH = 100  # argparse wraps to $COLUMNS: fixed, so the page is the same on every terminal


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, tuple[argparse.ArgumentParser, str]]:
    """Each subcommand's parser and its one-line help, as its parent's help lists it."""
    for action in parser._actions:  # argparse keeps its subparsers only here
        if isinstance(action, argparse._SubParsersAction):
            summaries = {choice.dest: choice.help or "" for choice in action._choices_actions}
            return {name: (sub, summaries.get(name, "")) for name, sub in action.choices.items()}
    return {}


def _sections(parser: argparse.ArgumentParser, words: tuple[str, ...]):
    """(command words, parser, one-line help) for every command under ``parser``, depth first,
    in its order."""
    for name, (sub, summary) in _subcommands(parser).items():
        yield (*words, name), sub, summary
        yield from _sections(sub, (*words, name))


def command_parsers() -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every command's parser by its words, ('calibrate',), ('sim', 'serve'), ...: what the page
    shows, and what tests/test_docs.py checks the commands a page names against."""
    from fieldcal.cli.main import build_parser

    return {words: parser for words, parser, _ in _sections(build_parser(), ())}


def commands_page() -> str:
    from fieldcal.cli.main import build_parser

    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_WIDTH)
    try:
        top = build_parser()
        lines = ["# Commands", "",
                 "Every `fieldcal` command with its options, as `fieldcal COMMAND --help` prints them. "
                 "This page is generated from the commands' own argument parsers each time the "
                 "guide is built (`docs/gen_commands_reference.py`), so it is always today's.", "",
                 "```text", top.format_help().rstrip(), "```", ""]
        for words, parser, summary in _sections(top, ()):
            lines += [f"## fieldcal {' '.join(words)}", ""]
            if summary:
                lines += [summary[0].upper() + summary[1:] + ".", ""]
            lines += ["```text", parser.format_help().rstrip(), "```", ""]
        return "\n".join(lines)
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous


def on_files(files, config):
    """The MkDocs hook (mkdocs.yml's hooks:): adds the page, made in memory, to the site's files."""
    from mkdocs.structure.files import File

    files.append(File.generated(config, PAGE, content=commands_page()))
    return files


if __name__ == "__main__":
    sys.stdout.write(commands_page())
