"""The ``taskrl`` subcommands, one file each (`taskrl.cli` dispatches); `parsing` holds what they share:
the parser that errors in one line, and every setting of a run as a flag."""
