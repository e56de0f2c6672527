"""Benchmarks for ``ssmpc bench NAME``. Each module defines ``NAME`` (str),
``DESCRIPTION`` (str), optionally ``add_arguments(parser)``, and ``run(args) -> list[dict]``
returning the ``cases`` of the bench JSON (see :mod:`services.bench._common`)."""
