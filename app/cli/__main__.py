"""`python -m radiosity.cli` runs the command line, as the `radiosity` script does."""

from radiosity.cli.commands import main

main()
