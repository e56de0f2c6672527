"""``ssmpc`` command line: the entry point (:mod:`services.cli.entry`) and the operator
and offline commands. Each command module defines ``register(subparsers)``."""

from services.cli.entry import build_parser, main

__all__ = ["build_parser", "main"]
