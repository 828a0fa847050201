"""Research harnesses: the studies behind the numbers in docs/ (the diagnosis' confusion matrix and
coverage, the independent simulator's coverage, the foreign-data corpus, the temperature pre-processing,
the sticky-valve frontier, ...). Each is a module with a ``main(argv)`` and runs as a script
(``python studies/NAME.py --help``) or as ``python -m studies.NAME``; the tests import them as modules
(the repository root is on pytest's path). Not installed: the wheel ships ``valve_env`` and ``agents``
only (pyproject.toml). The product benchmarks are in ``benchmarks/``.
"""
