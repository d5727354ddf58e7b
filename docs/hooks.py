"""MkDocs hook: the command-line reference is the commands' own ``--help``, generated at build time
so that it cannot drift from the parser."""

import argparse

MARKER = "<!-- percver --help -->"


def _parsers(parser: argparse.ArgumentParser, name: str):
    """(command line, parser) for ``parser`` and each of its sub-commands, depth first."""
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, child in action.choices.items():
                yield from _parsers(child, f"{name} {sub}")


def on_page_markdown(markdown, page, config, files):
    if MARKER not in markdown:
        return markdown
    from percver.cli import build_parser

    sections = []
    for name, parser in _parsers(build_parser(), "percver"):
        parser.prog = name
        sections.append(f"## `{name}`\n\n```text\n{parser.format_help().rstrip()}\n```\n")
    return markdown.replace(MARKER, "\n".join(sections))
