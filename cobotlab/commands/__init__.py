"""One module per ``cobotlab`` command: ``add_parser(subparsers)`` declares its arguments,
``run(args)`` does it (parses nothing, prints what the library returns)."""
