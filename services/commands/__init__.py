"""CLI subcommands. Each module defines ``register(subparsers)`` and is discovered
by :mod:`services.cli`; a module adds one or more ``ssmpc`` subcommands."""
