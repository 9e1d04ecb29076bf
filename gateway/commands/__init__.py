"""One module per `adxlgw` subcommand; each has add_parser(subparsers) and run(args) -> int."""
