"""One module per `stiction` command: ``add_arguments(parser)`` and ``run(args) -> int``."""
