"""The subcommands of ``bodebench``, one module each (``bodebench.apps.cli`` parses the command line and calls
them). Only the standard library at the top of each: a command imports what it uses when it runs."""
