"""Subcommands of the ``turntable-sim`` console command, one module each."""
