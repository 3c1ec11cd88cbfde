"""The kit's version, on the ground floor (the writer, the reports and the CLI print it)."""

__version__ = "0.1.0"
