"""The ``rollergear`` command: ``main`` (a static table of the subcommand modules) and one module
per group of subcommands, sharing ``args``.
"""
