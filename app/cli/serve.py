"""calib serve: the dashboard, with the desk's robots and those met on ROS 2 graphs or through NAOqi."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypeVar

from calib_core import InputError

from ..web.limits import DEFAULT_MAX_ROWS, DEFAULT_MAX_UPLOAD_BYTES, Limits
from .common import Command

if TYPE_CHECKING:
    from ..drivers.naoqi.connection import Connection as NaoqiConnection
    from ..drivers.registry import Options
    from ..drivers.ros2.connection import Meeting
    from ..robots.desk_config import DeskConfig


class _Connection(Protocol):
    """What the desk reads of a robot's connection file (a ROS 2 or a NAOqi one) before it connects."""

    @property
    def robot(self) -> str: ...

    @property
    def path(self) -> Path: ...


Conn = TypeVar("Conn", bound=_Connection)


def _serve_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8000, help="the page and the API (default 8000)")
    p.add_argument(
        "--viser-port",
        type=int,
        default=0,
        help="the 3-D scene server's port, on 127.0.0.1 only: browsers reach the scene through --port "
        "(default: any free one)",
    )
    p.add_argument("--data-dir", default="data", help="where sessions, calibrations and history live (default data/)")
    p.add_argument(
        "--sim-speed", type=float, default=1.0, help="the simulated robots' speed, times their joint velocity limits"
    )
    p.add_argument(
        "--desk",
        metavar="CONFIG.yaml",
        help="the desk configuration: which robots (name, profile, driver); default: the built-in robots, simulated",
    )
    p.add_argument(
        "--ros2",
        action="append",
        default=[],
        metavar="CONNECTION.yaml",
        help="a robot on its ROS 2 graph (specs ros2.md; the ros2 extra); may be given more than once",
    )
    p.add_argument(
        "--naoqi",
        action="append",
        default=[],
        metavar="CONNECTION.yaml",
        help="a NAO through NAOqi (specs naoqi.md; the naoqi extra); may be given more than once",
    )
    p.add_argument(
        "--max-upload-mb",
        type=float,
        default=DEFAULT_MAX_UPLOAD_BYTES / (1024 * 1024),
        help="the largest file an import or a robot's upload may be, MB (default %(default)g)",
    )
    p.add_argument(
        "--max-rows",
        type=int,
        default=DEFAULT_MAX_ROWS,
        help="the most rows a CSV import, and observations a calibration, may have (default %(default)d)",
    )
    p.add_argument(
        "--new-token",
        action="store_true",
        help="bound off loopback: replace the access token (printed once) with a new one",
    )


def _serve(args: argparse.Namespace) -> int:
    if not 0 < args.port < 65536:
        raise InputError(f"--port {args.port} is not a TCP port")
    if not 0 <= args.viser_port < 65536:
        raise InputError(f"--viser-port {args.viser_port} is not a TCP port")
    if not 0.1 <= args.sim_speed <= 100:
        raise InputError(f"--sim-speed {args.sim_speed} must be between 0.1 and 100")
    if not 0.001 <= args.max_upload_mb <= 10_000:
        raise InputError(f"--max-upload-mb {args.max_upload_mb:g} must be between 0.001 and 10000")
    if args.max_rows < 1:
        raise InputError(f"--max-rows {args.max_rows} must be at least 1")
    limits = Limits(upload_bytes=int(args.max_upload_mb * 1024 * 1024), rows=args.max_rows)
    # Meeting a robot mostly waits for it to answer (a ROS 2 robot's latched description: up to 3 s), so the
    # ROS 2 robots are listened to first and everything else is done meanwhile: the desk file read (before
    # anything starts: nothing is written until the robots are checked), the web stack imported (loaded only for
    # this subcommand; for NAOqi, in a thread while its sessions open).
    meetings = _meet_ros2(args.ros2) if args.ros2 else []
    web = threading.Thread(target=_import_quietly, args=("..web.server",), daemon=True)
    try:
        from ..robots.desk_config import load_desk_config

        config = None if args.desk is None else load_desk_config(Path(args.desk))
        if meetings:
            _import_quietly("..web.server")
            config = _with_ros2(config, meetings, Path(args.data_dir))
        if args.naoqi:
            web.start()
            config = _with_naoqi(config, args.naoqi)
    finally:
        for meeting in meetings:  # not reached: the desk file or a robot before it was refused
            meeting.close()
        if web.is_alive():
            web.join()
    from ..web.server import serve

    serve(
        args.host,
        args.port,
        Path(args.data_dir),
        viser_port=args.viser_port,
        config=config,
        time_scale=args.sim_speed,
        new_token=args.new_token,
        limits=limits,
    )
    return 0


def _import_quietly(module: str) -> None:
    """Import ahead in a thread (`module` relative to this package, as its imports name it); a failure is left to
    the import that needs the module (said as the command's error, not as a thread's traceback)."""
    with contextlib.suppress(Exception):  # the main thread's import raises it again
        importlib.import_module(module, __package__)


def _meet_ros2(files: list[str]) -> list[Meeting]:
    """Every ROS 2 connection file checked, then each robot listened to at once
    (app/drivers/ros2/connection.Meeting)."""
    from ..drivers.ros2 import require

    require()
    from ..drivers.ros2.connection import Meeting, load_connection

    conns = [load_connection(Path(f)) for f in files]  # every file checked before any robot is met
    meetings: list[Meeting] = []
    try:
        for conn in conns:
            meetings.append(Meeting(conn))
    except BaseException:
        for meeting in meetings:
            meeting.close()
        raise
    return meetings


def _with_ros2(config: DeskConfig | None, meetings: list[Meeting], data_dir: Path) -> DeskConfig:
    """The desk's robots and those on ROS 2 graphs, each checked on its graph before the desk starts; a robot's
    meeting is taken from `meetings` (in order) as it is connected."""
    from ..drivers.ros2.connection import connect

    conns = [meeting.conn for meeting in meetings]
    return _with_robots(config, conns, lambda _conn: connect(meetings.pop(0), data_dir), "ros2")


def _with_robots(
    config: DeskConfig | None, conns: list[Conn], connect: Callable[[Conn], tuple[str, Options]], kind: str
) -> DeskConfig:
    """The desk's robots (its configuration's, else the defaults) and one more of driver `kind` per connection,
    `connect(conn)` giving its profile reference and driver options; the first is the one the page shows."""
    from dataclasses import replace

    from ..drivers.registry import DriverSpec
    from ..robots.desk_config import RobotConfig, default_config

    config = config or default_config()
    robots = list(config.robots)
    for conn in conns:
        if conn.robot in {r.name for r in robots}:
            raise InputError(f"robot: '{conn.robot}' is on the desk already", file=str(conn.path))
        ref, options = connect(conn)
        robots.append(RobotConfig(conn.robot, ref, DriverSpec(kind, options), "config"))
    return replace(config, robots=tuple(robots), connected=config.connected or conns[0].robot)


def _with_naoqi(config: DeskConfig | None, files: list[str]) -> DeskConfig:
    """The desk's robots and the NAOs reached through NAOqi. A robot that does not answer yet is said so; the desk
    starts all the same and connects to it once it answers."""
    from ..drivers.naoqi import open_session, require

    require()
    from ..drivers.naoqi.connection import load_connection

    def connect(conn: NaoqiConnection) -> tuple[str, Options]:
        url = conn.options["url"]
        try:
            open_session(url).close()
        except RuntimeError as exc:
            print(
                f"calib serve: {conn.robot}: NAOqi does not answer at {url} ({exc}); the desk starts and connects "
                "to it once it answers",
                file=sys.stderr,
                flush=True,
            )
        return conn.profile, conn.options

    conns = [load_connection(Path(f)) for f in files]  # every file checked before any robot is asked
    return _with_robots(config, conns, connect, "naoqi")


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
SERVE = Command(
    "serve", "start the dashboard (simulated robots, sample sessions) in a browser", _serve_arguments, _serve
)
