"""The `radiosity` command: options, subcommands and the summary they print."""
