"""Subcommands of `hsio`, one module each (registered in hsio.cli.LAZY_COMMANDS)."""
