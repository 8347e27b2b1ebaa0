"""The ``bt`` command: one typed CLI over every job (tyro builds it from the commands' signatures).

Commands of other installed packages join through the ``bt.commands`` entry-point group (bt_teleop
adds ``bt teleop`` that way), so this package never imports them. Results go to stdout (a table,
or one JSON object with ``--json``); progress bars, warnings and errors go to stderr. Errors bt
raises on purpose print one line and exit with status 2.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from importlib.metadata import entry_points

import tyro

from bt_pipeline.cli.data_commands import clean, score, synth
from bt_pipeline.cli.evaluate_commands import evaluate, reproduce
from bt_pipeline.cli.interop_commands import export, import_, view
from bt_pipeline.exceptions import BtError, ConfigError

PLUGIN_GROUP = "bt.commands"
"""Entry-point group of commands other packages add to ``bt`` (``name = "module:function"``)."""

BUILT_IN: dict[str, Callable[..., object]] = {
    "score": score,
    "synth": synth,
    "clean": clean,
    "evaluate": evaluate,
    "reproduce": reproduce,
    "export": export,
    "import": import_,
    "view": view,
}


def commands() -> dict[str, Callable[..., object]]:
    """Every ``bt`` command: the installed plugins' (``bt teleop``) first, then the built-in ones.

    A plugin that fails to load, or takes a built-in's name, is left out with a one-line warning;
    the other commands still work.
    """
    found: dict[str, Callable[..., object]] = {}
    for point in sorted(entry_points(group=PLUGIN_GROUP), key=lambda p: p.name):
        if point.name in BUILT_IN:
            logging.getLogger("bt").warning(
                "command %r of %s is left out: bt has a command of that name",
                point.name,
                point.value,
            )
            continue
        try:
            found[point.name] = point.load()
        except Exception as error:  # a broken plugin must not take the other commands down
            logging.getLogger("bt").warning(
                "command %r (%s) is left out: it failed to load: %s", point.name, point.value, error
            )
    return {**found, **BUILT_IN}


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
            commands(),
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
