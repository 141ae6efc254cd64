"""The `calib` command (specs/cli.md): one module per group of subcommands, each adding its subcommands' arguments
and running them (calibration.py: solve, predict, evaluate, self-observe, export; plan.py; simulate.py;
detect.py: detect-sphere, detect-board; handeye.py; import_bag.py; serve.py; sim_robots.py: sim-ros2, sim-naoqi);
here the parser they make together, and `main`.

Bad input ends with exit status 2 and a message naming file, line and column; an internal failure
(a bug) with exit status 1 and one line (set CALIB_DEBUG=1 for the traceback); never a traceback
for the user's mistakes.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Sequence

from calib_core import InputError

from . import calibration, detect, handeye, import_bag, plan, serve, sim_robots, simulate

SIGPIPE_STATUS = 141  # 128 + SIGPIPE: how a shell reports a command that wrote to a closed pipe

# The subcommands in the order `calib --help` lists them.
COMMANDS = (
    calibration.SOLVE,
    calibration.PREDICT,
    plan.PLAN,
    calibration.EVALUATE,
    calibration.SELF_OBSERVE,
    calibration.EXPORT,
    simulate.SIMULATE,
    detect.DETECT_SPHERE,
    detect.DETECT_BOARD,
    handeye.HANDEYE,
    import_bag.IMPORT_BAG,
    serve.SERVE,
    sim_robots.SIM_ROS2,
    sim_robots.SIM_NAOQI,
)


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors name the subcommand and exit 2 without a traceback."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="calib", description="Kinematic self-calibration of robots that see themselves.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for command in COMMANDS:
        command.arguments(sub.add_parser(command.name, help=command.help))
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit status. A reader that closes our output early (`calib ... | head -1`) ends
    the command quietly with 141, the status of a command a shell sees killed by SIGPIPE (Python ignores the
    signal, so the write raises BrokenPipeError instead: never a traceback or an "internal error")."""
    try:
        try:
            status = _run(argv)
        except SystemExit as exc:  # argparse: --help, a usage error
            status = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 2
        sys.stdout.flush()  # a closed pipe shows here rather than at the interpreter's exit
    except BrokenPipeError:
        # Whatever is left in the buffer can never be written: point stdout at /dev/null so that the
        # interpreter's own flush at exit does not report the broken pipe once more.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return SIGPIPE_STATUS
    return status


def _run(argv: Sequence[str] | None) -> int:
    args = _parser().parse_args(argv)
    try:
        run = {command.name: command.run for command in COMMANDS}[args.command]
        return run(args)
    except InputError as exc:
        print(f"calib {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"calib {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # our output's reader went away: main ends quietly
        raise
    except Exception as exc:  # a bug: one line, the traceback only on request
        if os.environ.get("CALIB_DEBUG"):
            traceback.print_exc()
        print(
            f"calib {args.command}: internal error ({exc.__class__.__name__}: {exc}); please report it",
            file=sys.stderr,
        )
        return 1
