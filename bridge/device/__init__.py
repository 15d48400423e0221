"""One unit over a port: bring-up, commands with timeouts and retries, operator actions.

``Port`` opens any pyserial URL and stamps each read on the host's raw and realtime
clocks (``bridge.device.clock``); ``Session`` brings a unit up, sends commands while it
streams and reads its records; ``run_action`` runs the operator actions that
``gx3 configure`` and a bridge's command queryable share; ``find_link`` tells which link
a device is on (a UART, the unit's own USB port, a USB-serial adapter). Nothing writes
the unit's non-volatile memory unless the caller asks for it, command by command.

The names below are imported on first use, so that ``bridge.device.link`` alone (as the
emulator and the timing layer use it) loads neither pyserial nor libc.

```python
from bridge.device import Session, find_baud

port, baud = find_baud("/dev/ttyUSB0", 115_200)
try:
    info = Session(port).identify()
finally:
    port.close()
```
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported

if TYPE_CHECKING:
    from bridge.device.actions import ACTIONS, Action, run_action
    from bridge.device.clock import HostSync, host_sync
    from bridge.device.link import Link, find_link
    from bridge.device.port import Port
    from bridge.device.session import Session, UnitInfo, find_baud

__all__ = ["ACTIONS", "Action", "HostSync", "Link", "Port", "Session", "UnitInfo", "find_baud",
           "find_link", "host_sync", "run_action"]

# the module of each name above, imported when the name is first asked for
_MODULES = {"ACTIONS": ".actions", "Action": ".actions", "run_action": ".actions",
            "HostSync": ".clock", "host_sync": ".clock", "Link": ".link", "find_link": ".link",
            "Port": ".port", "Session": ".session", "UnitInfo": ".session",
            "find_baud": ".session"}


def __getattr__(name: str) -> object:
    return imported(__name__, _MODULES, name)
