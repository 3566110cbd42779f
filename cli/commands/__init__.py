"""Subcommands of ``dtid``: each module has ``add_parser(subparsers)`` and a ``run(args)``."""
