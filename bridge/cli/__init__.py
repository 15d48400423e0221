"""The `gx3` command line: one Typer app, one module per group of commands."""

import signal
import sys

# Ctrl-C while the commands import (a fraction of a second) ends quietly, not with a
# traceback; Python's own handler is back before any command runs.
signal.signal(signal.SIGINT, lambda *_: sys.exit(130))

from typer.models import CommandInfo

from bridge.cli import (
    align,
    archive,
    bridge,
    commands,
    decode,
    demo,
    importlog,
    magcal,
    noise,
    operate,
    record,
    router,
    sim,
    viz,
)
from bridge.cli.common import app

#: Help panels, in the order `gx3 --help` shows them, each with its commands in order.
PANELS = {
    "Run a fleet": ("demo", "bridge", "record", "view", "router", "sim"),
    "Operate a unit": ("info", "configure", "capture-bias", "set-timer", "stationary-test",
                       "reset"),
    "Archives": ("export", "replay", "import", "rrd", "repair", "calibrate-mag", "allan",
                 "align"),
    "Bytes and protocol": ("decode", "commands"),
}


def _arrange() -> None:
    order = [name for names in PANELS.values() for name in names]
    panel = {name: title for title, names in PANELS.items() for name in names}

    def name(info: CommandInfo) -> str:
        callback = info.callback.__name__ if info.callback else ""
        return info.name or callback.replace("_", "-")

    for info in app.registered_commands:
        info.rich_help_panel = panel.get(name(info), "Other")
    app.registered_commands.sort(
        key=lambda info: order.index(name(info)) if name(info) in order else len(order))


_arrange()
signal.signal(signal.SIGINT, signal.default_int_handler)

__all__ = ["align", "app", "archive", "bridge", "commands", "decode", "demo", "importlog", "magcal",
           "noise", "operate", "record", "router", "sim", "viz"]
