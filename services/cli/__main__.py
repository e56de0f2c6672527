"""``python -m services.cli``: the ``ssmpc`` command."""

import sys

from services.cli.entry import main

sys.exit(main())
