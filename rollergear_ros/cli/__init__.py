"""The ``rollergear`` command: ``main`` (the table of verbs and the dispatch) and one module per verb,
sharing ``args``.
"""

#: the command is ``main.main`` (``rollergear``); nothing imports from the top of the house
__all__: list[str] = []
