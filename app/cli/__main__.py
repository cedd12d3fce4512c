"""`python -m radiosity.cli` runs the command line, as the `radiosity` script does (Ctrl-C
while the command line is still being imported: the one line, no traceback)."""

import sys

try:
    from radiosity.cli.commands import main
except KeyboardInterrupt:
    print("interrupted", file=sys.stderr)
    sys.exit(130)

main()
