"""``bodebench ports``: the serial ports and CAN interfaces of this machine."""

from __future__ import annotations

import argparse
import logging

from bodebench.apps.commands.common import _ArgumentError

log = logging.getLogger("bodebench")


def _ports(args: argparse.Namespace) -> int:
    import json

    import serial.tools.list_ports

    serial_ports = [{"port": p.device, "description": p.description or "", "hwid": p.hwid or ""}
                    for p in sorted(serial.tools.list_ports.comports(), key=lambda p: p.device)]
    can_configs: list[dict[str, object]] = []
    unusable: list[dict[str, str]] = []
    if not args.no_can:
        from bodebench.drivers.ports import detect_can

        try:
            found = detect_can(args.can)
        except ValueError as exc:
            raise _ArgumentError(f"--can: {exc}") from None
        can_configs = [{k: v if isinstance(v, (str, int, float, bool)) or v is None else str(v)
                        for k, v in c.items()} for c in found.configs]
        unusable = [{"interface": name, "why": why} for name, why in found.unusable]
    if args.json:
        print(json.dumps({"serial": serial_ports, "can": can_configs, "can_unusable": unusable}, indent=2))
        return 0
    print(f"serial ports (pyserial): {len(serial_ports)}")
    for p in serial_ports:
        print(f'  port = "{p["port"]}"    # {p["description"]}; {p["hwid"]}')
    if args.no_can:
        return 0
    where = ", ".join(args.can) if args.can else "every interface"
    print(f"CAN configurations (python-can, {where}): {len(can_configs)}")
    for c in can_configs:
        print("  " + ", ".join(f"{k} = {json.dumps(v)}" for k, v in c.items()))
    if unusable:
        print(f"CAN interfaces that cannot be used here: {len(unusable)}")
        for item in unusable:
            print(f"  {item['interface']}: {item['why']}")
    return 0
