"""Command line: `python -m ur_emulator --host 127.0.0.2 --q0 0 -1.5708 1.5708 -1.5708 -1.5708 0`
(with tests/ on PYTHONPATH) runs one emulated controller until it is stopped."""

from __future__ import annotations

import argparse

from .arm import HOME
from .server import serve


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="ur_emulator", description=__doc__)
    parser.add_argument("--host", default="127.0.0.1", help="loopback address to listen on")
    parser.add_argument("--q0", type=float, nargs=6, default=list(HOME), help="initial joints")
    parser.add_argument("--tau", type=float, default=0.03, help="joint lag time constant [s]")
    parser.add_argument("--unlock-delay", type=float, default=5.0,
                        help="seconds before a protective stop may be unlocked")
    parser.add_argument("--parent-pid", type=int, default=None,
                        help="exit when this process is no longer the parent")
    parser.add_argument("--lifetime", type=float, default=300.0, help="hard cap [s]")
    parser.add_argument("--control-port", type=int, default=0,
                        help="port of the JSON-lines control channel (0: any free port)")
    args = parser.parse_args(argv)
    serve(args.host, args.q0, tau=args.tau, unlock_delay=args.unlock_delay,
          parent_pid=args.parent_pid, lifetime=args.lifetime, control_port=args.control_port)


if __name__ == "__main__":
    main()
