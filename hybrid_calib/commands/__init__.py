"""One module per ``hybrid-calib`` subcommand; each defines ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. The modules are thin: they parse arguments and call typed functions."""
