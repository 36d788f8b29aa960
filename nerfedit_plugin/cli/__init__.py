"""The ``nerfedit`` command line: one module per subcommand."""
