"""The ``bt`` command: one typed CLI over every job (tyro builds it from the commands' signatures).

Results go to stdout (a table, or one JSON object with ``--json``); progress bars, warnings and
errors go to stderr. Errors bt raises on purpose print one line and exit with status 2.
"""

from __future__ import annotations

import logging
import sys

import tyro

from bt_pipeline.cli.data_commands import clean, score, synth
from bt_pipeline.cli.evaluate_commands import evaluate, reproduce
from bt_pipeline.cli.interop_commands import export, import_, view
from bt_pipeline.cli.teleop_command import teleop
from bt_pipeline.exceptions import BtError, ConfigError

COMMANDS = {
    "teleop": teleop,
    "score": score,
    "synth": synth,
    "clean": clean,
    "evaluate": evaluate,
    "reproduce": reproduce,
    "export": export,
    "import": import_,
    "view": view,
}


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``bt`` console script and ``python -m bt_pipeline``."""
    logging.basicConfig(level=logging.INFO, format="bt: %(message)s", stream=sys.stderr)
    argv = sys.argv[1:] if args is None else args
    if argv[:1] in (["--version"], ["-V"]):
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(f"bt {version('bt')}")
        except PackageNotFoundError:  # run from a source tree that was never installed
            print("bt (not installed; source tree)")
        return
    try:
        tyro.extras.subcommand_cli_from_dict(
            COMMANDS,
            prog="bt",
            description="Beyond the Teacher: score and clean demos. `bt --version` prints the "
            "version.",
            args=args,
        )
    except (BtError, ConfigError) as error:
        print(f"bt: error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    except BrokenPipeError:
        # stdout closed early (e.g. piped into `head`): not an error of ours.
        sys.stderr.close()
        raise SystemExit(0) from None
    except KeyboardInterrupt:
        print("bt: interrupted; no partial output was written", file=sys.stderr)
        raise SystemExit(130) from None
