"""``python -m field.cli``: the ``loggrasp`` console script."""

from field.cli import main

main()
