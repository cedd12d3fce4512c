"""The `radiosity` command: options, subcommands and the summary they print."""


def run():
    """The `radiosity` script (and `python -m radiosity.cli`): the command line, with Ctrl-C
    while it is still being imported answered by the one line, no traceback."""
    import sys

    try:
        from radiosity.cli.commands import main
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
    main()
