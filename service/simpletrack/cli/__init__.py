"""The ``simpletrack`` command: ``main.py`` parses, one module per subcommand registers itself."""
