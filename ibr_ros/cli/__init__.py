"""The ``ibr`` command line tool: one module per subcommand group, each with ``register()``."""
