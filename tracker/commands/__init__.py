"""One module per `tracker` subcommand (see tracker.cli)."""
