"""Sub-commands of the CLI: every public module here has ``register(subparsers)``."""
