"""Subcommands of the ``armbench`` command line, one module each."""
