"""One module per ``nifo`` sub-command.

Each module defines ``HELP`` (one line for ``nifo --help``), ``add_arguments(parser)``
and ``run(args) -> int``. :mod:`nifo.cli` lists them in ``COMMANDS``.
"""
