"""``python -m services.cli``: the ``ssmpc`` command."""

import sys

from services.cli.entry import main

if __name__ == "__main__":  # not in a process spawned from it (multiprocessing)
    sys.exit(main())
