"""python -m emfabric: the command line."""

from emfabric.cli import main

main()
