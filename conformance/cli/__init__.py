"""The command line: ``main`` parses and dispatches; every other module is one group of
sub-commands with ``register(subparsers)``.
"""
