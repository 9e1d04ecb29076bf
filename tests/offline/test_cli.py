"""The command line builds only the chosen subcommand's parser: the daemon's start (and a
restart after a crash, while a PLC gets no answer) does not wait for the offline tools."""
import re
import subprocess
import sys
from pathlib import Path

from gateway.cli import COMMAND_MODULES, build_parser, chosen_command

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import sys
from gateway.cli import build_parser, chosen_command
build_parser(only=chosen_command(sys.argv[1:]))
heavy = sorted(m for m in ("scipy.stats", "scipy.optimize", "gateway.core.simulator", "gateway.core.diagnosis")
               if m in sys.modules)
print(",".join(heavy))
"""


def loaded_after_parser(*argv: str) -> str:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], cwd=ROOT, capture_output=True, text=True,
                         timeout=120, check=True)
    return out.stdout.strip()


def test_the_daemon_command_does_not_import_the_offline_tools():
    assert loaded_after_parser("run", "--config", "x.toml") == ""
    assert loaded_after_parser("-v", "run") == ""


def test_without_a_known_command_every_subcommand_is_there():
    # (the probe itself: an unknown or missing command builds the whole parser)
    assert "gateway.core.simulator" in loaded_after_parser("--help")
    assert chosen_command(["nosuch"]) is None and chosen_command(["-v"]) is None
    assert chosen_command(["-v", "fit-drift", "a.csv"]) == "fit-drift"
    assert listed(build_parser()) == list(COMMAND_MODULES)


def test_each_command_alone_builds_and_parses_its_help():
    for command in COMMAND_MODULES:
        assert listed(build_parser(only=command)) == [command]


def listed(parser) -> list[str]:
    """The subcommands `--help` lists (one per line, indented, before its help text)."""
    return re.findall(r"^    ([a-z][a-z-]*)(?:\s|$)", parser.format_help(), flags=re.MULTILINE)
