"""``smarts viz [PATH]`` (also ``python -m smarts.viz``): the diagnostic viewer in a browser."""

from __future__ import annotations

import argparse
import sys

from smarts import exit_codes
from smarts.viz.live import DEFAULT_HOST, DEFAULT_PORT

DESCRIPTION = """Serve the diagnostic viewer: recorded episodes under PATH (episode recordings and
benchmark logs, e.g. runs/benchmark/adaptive/latest/logs) and live envs (smarts.viz.WatchedEnv(env,
live=True)). Open the printed address in a browser."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", nargs="?", default=None,
                        help="a recording (.rec.npz), a benchmark episode log (.npz) or a folder of them; "
                             "none: wait for live envs")  # fmt: skip
    parser.add_argument("--host", default=DEFAULT_HOST,
                        help=f"interface to bind (default: {DEFAULT_HOST}; others need --allow-remote)")  # fmt: skip
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default: {DEFAULT_PORT})")
    parser.add_argument("--allow-remote", action="store_true",
                        help="allow a --host other than this machine, and pages that reach it by an IP address or "
                             "this machine's name (default: only localhost, 127.0.0.1 and [::1] on the bound "
                             "port); the viewer has no authentication")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from smarts.viz.server import check_bind, serve

    try:
        check_bind(args.host, args.allow_remote)
        if not 0 <= args.port <= 65535:
            raise ValueError(f"--port {args.port}: expected 0 to 65535")
        serve(args.path, args.host, args.port, allow_remote=args.allow_remote)
    except ValueError as err:  # refused bind, port in use, unreadable recording or log: say which and why
        print(f"error: {err}", file=sys.stderr)
        return exit_codes.BAD_INPUT
    except KeyboardInterrupt:
        return exit_codes.OK
    return exit_codes.OK


def add_viz_command(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """``smarts viz`` (listed in ``smarts.__main__``)."""
    parser.description = DESCRIPTION
    add_arguments(parser)
    parser.set_defaults(run=run)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m smarts.viz", description=DESCRIPTION)
    add_arguments(parser)
    return run(parser.parse_args(argv))
