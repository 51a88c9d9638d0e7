"""``python -m scenarios`` is the ``omnibench`` command."""

from scenarios.cli import main

main()
