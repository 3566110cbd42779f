"""The command-line reference (docs/cli.md), generated from the parser itself.

``python -m dtid.cli.reference > docs/cli.md`` writes it; ``tests/test_cli_reference.py`` fails
when the page and the parser disagree, so the page cannot drift from the options.
"""

from __future__ import annotations

import argparse
import functools

from dtid.cli import build_parser

WIDTH = 100
"""Line width of the help texts, characters (fixed: the terminal's would change the page)."""


def _help(parser: argparse.ArgumentParser) -> str:
    parser.formatter_class = functools.partial(argparse.HelpFormatter, width=WIDTH)
    return parser.format_help().rstrip()


def render() -> str:
    """The reference page in Markdown: ``dtid`` and each subcommand's help."""
    parser = build_parser()
    (subparsers,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    lines = [
        "# Command-line reference",
        "",
        "Generated from the parser by `python -m dtid.cli.reference > docs/cli.md`; "
        "`tests/test_cli_reference.py` checks that it is current.",
        "",
        "```text",
        _help(parser),
        "```",
    ]
    for name, command in subparsers.choices.items():
        lines += ["", f"## `dtid {name}`", "", "```text", _help(command), "```"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(render(), end="")
