"""Seed case studies for ``ssmpc reproduce ID``: one module per seed chapter.

Each module defines ``RESULTS: dict[str, Callable[[StudyContext], ReproduceResult]]``
mapping seed-result ids (``R3.2`` …) to a function; see :mod:`services.reproduce`."""
