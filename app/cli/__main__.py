"""`python -m radiosity.cli` runs the command line, as the `radiosity` script does."""

from radiosity.cli import run

run()
