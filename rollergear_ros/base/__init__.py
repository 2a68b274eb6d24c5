"""The base: names other tools depend on (``interface``), the output-channel table
(``output_channels``), the one exception family (``errors``), safe YAML, atomic file writing,
progress bars and graceful stopping.  Imports nothing else of the package.
"""
