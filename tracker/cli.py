"""Command line: ``tracker SUBCOMMAND [--config FILE] ...``.

Each subcommand lives in its own module that defines ``register(subparsers,
common)`` (adding its parser with ``common`` as a parent and
``set_defaults(func=...)``) and a function ``func(args, cfg) -> int`` that
receives the parsed arguments and the validated configuration.

Errors a user can fix (:class:`tracker.errors.UserError`: a bad config, a
missing or corrupt catalogue, an unreadable file, a wrong argument; and the
operating system's refusals, such as a missing file or a folder that cannot
be written) print one line to stderr and exit with status 2; no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import platform
import sys

import cv2
import numpy as np

from tracker import __version__
from tracker.config import load_config, render_markdown_table, render_yaml
from tracker.errors import UserError

__all__ = ["main", "UserError", "build_parser"]

# Subcommand modules, in the order `tracker --help` lists them.
COMMAND_MODULES = (
    "tracker.commands.replay",
    "tracker.commands.simulate",
    "tracker.commands.demo",
    "tracker.commands.bench",
    "tracker.commands.run",
    "tracker.commands.record",
    "tracker.commands.focus",
    "tracker.commands.selftest",
    "tracker.commands.monitor",
    "tracker.commands.calibrate",
    "tracker.commands.database",
    "tracker.commands.validate",
)


def version_text() -> str:
    """What ``tracker --version`` prints: this program and what it runs on."""
    return (f"tracker {__version__} (Python {platform.python_version()}, numpy "
            f"{np.__version__}, OpenCV {cv2.__version__})")


def _os_error_text(exc: OSError) -> str:
    """One line for an error of the operating system: the path and what went wrong."""
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what


def _config_command(args: argparse.Namespace, cfg) -> int:
    if args.markdown:
        sys.stdout.write(render_markdown_table())
    else:
        sys.stdout.write(render_yaml(cfg, comments=not args.bare))
    return 0


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", metavar="FILE",
                        help="YAML configuration (default: the built-in defaults; "
                             "see `tracker config`)")
    common.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    parser = argparse.ArgumentParser(
        prog="tracker", description="Star tracker: detect, identify, solve attitude, "
                                    "report over a UART.")
    parser.add_argument("--version", action="version", version=version_text())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser("config", parents=[common], help="print the effective configuration")
    p.add_argument("--bare", action="store_true", help="without the comments")
    p.add_argument("--markdown", action="store_true",
                   help="every key as a Markdown table (the README's reference)")
    p.set_defaults(func=_config_command)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub, common)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    try:
        cfg = load_config(args.config)
        return int(args.func(args, cfg) or 0)
    except UserError as exc:
        print(f"tracker {args.command}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"tracker {args.command}: {_os_error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
