"""One exception family for the gateway; each carries the exit code the CLI returns.

Exit codes (documented in README.md):
    0  success
    1  unexpected internal error (a bug: the traceback is printed)
    2  bad input: command line, config file, recording
    3  a device or port could not be used (with --once)
"""


class GatewayError(Exception):
    exit_code = 1


class InputError(GatewayError):
    """Something from outside is wrong: the message names what and where."""

    exit_code = 2


class RecordingError(InputError):
    pass


class ConfigError(InputError):
    pass


class DeviceError(GatewayError):
    exit_code = 3
