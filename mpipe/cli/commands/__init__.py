"""Command modules of the ``mpipe`` command line, one per subcommand."""
