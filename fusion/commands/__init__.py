"""Subcommands of the fusion CLI: each module has register(subparsers) that sets func=run."""
