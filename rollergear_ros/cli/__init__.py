"""The ``rollergear`` command: ``main`` (a static table of the subcommand modules) and one module
per group of subcommands, sharing ``args``.
"""

#: the command is ``main.main`` (``rollergear``); nothing imports from the top of the house
__all__: list[str] = []
