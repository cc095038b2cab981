"""docs/cli.md is the command line's own help, word for word: a change to an option changes the reference.

The reference is made from the parser (``caustica --help`` and each command's ``--help`` at 100
columns) and ``caustica methods``; the test fails when docs/cli.md differs, and says how to
rewrite it:

    .venv/bin/python tests/test_docs_cli.py --update
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
from pathlib import Path

CLI_MD = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
COLUMNS = "100"

INTRO = """# Command-line reference

This page is the command line's own `--help`, generated from the parser (`tests/test_docs_cli.py`
checks that it is current; `python tests/test_docs_cli.py --update` rewrites it). Errors in the
input print one line `caustica: error: ...` and exit with status 2; Ctrl-C exits with 130 and
SIGTERM with 143, after saving what a multi-pass render finished. The README shows the common
uses; [architecture.md](architecture.md) how the pieces fit.
"""


def cli_reference() -> str:
    from caustica import cli

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = COLUMNS
    try:
        parser = cli._build_parser()
        parts = [INTRO, "## caustica\n\n```text\n" + parser.format_help().rstrip() + "\n```\n"]
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        for name, p in sub.choices.items():
            parts.append(f"## caustica {name}\n\n```text\n{p.format_help().rstrip()}\n```\n")
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            cli.main(["methods"])
        parts.append("## The methods' parameters (`caustica methods`)\n\n```text\n" + out.getvalue().rstrip()
                     + "\n```\n")
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(parts)


def test_docs_cli_is_the_help_of_the_command_line():
    assert CLI_MD.exists(), "docs/cli.md is missing: python tests/test_docs_cli.py --update"
    assert CLI_MD.read_text() == cli_reference(), \
        "docs/cli.md differs from the command line's help: python tests/test_docs_cli.py --update"


if __name__ == "__main__":
    if sys.argv[1:] != ["--update"]:
        sys.exit("usage: python tests/test_docs_cli.py --update")
    CLI_MD.write_text(cli_reference())
    print(f"wrote {CLI_MD}")
