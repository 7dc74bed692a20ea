"""``python -m calibration``: calibrate the CRT with a photometer."""

from __future__ import annotations

import argparse
import sys


def _cmd_ports(args) -> int:
    from calibration.ports import available_ports

    ports = available_ports()
    if not ports:
        print("no serial ports found; check the photometer's cable and power, and that the "
              "USB-serial adapter's driver is loaded (dmesg)")
        return 0
    for p in ports:
        print(f"{p['device']}\t{p['description']}\t{p['hwid']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m calibration", description="Calibrate the display.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("ports", help="list serial ports")
    p.set_defaults(func=_cmd_ports)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
