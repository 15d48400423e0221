"""What commands print for people: every count with thousands separators, as
``bridge._text`` writes them, so that ``2,094 instants`` never stands beside ``7858
samples``.

Each line a command prints at its end, built in-process from counts in the thousands.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

from rich.console import Console

from bridge.archive.repair import RepairReport
from bridge.cli.demo import _summary
from bridge.export.ros2_bag import Ros2Written
from bridge.export.run import Exported
from bridge.fleet.demo import UnitOutcome
from bridge.ingest.bytelog import Imported
from bridge.protocol.framer import FramerStats

#: Four digits or more in a row: a count without its separators (hex such as 0xC8, and
#: the digits after a decimal point, are not counts).
BARE = re.compile(r"(?<![\w.,])\d{4,}")


def rendered(table: object) -> str:
    console = Console(width=200, record=True)
    with console.capture():
        console.print(table)
    return console.export_text()


def test_every_count_printed_has_thousands_separators() -> None:
    stats = FramerStats(records=Counter({0xC8: 1199, 0xDB: 1}), checksum_failures=1005,
                        implausible=1001, bytes_skipped=1067, bytes_fed=80_400, resyncs=1002)
    imported = Imported("moor", samples=Counter({0xCB: 12_000}), missing=1500, stats=stats,
                        first_ns=0, last_ns=1_200 * 10**9)
    texts = {
        "export, aligned": Exported(Path("t.csv"), 7858, 2, align_hz=100.0, instants=2094,
                                    events_path=Path("e.csv"), events=1234).text(),
        "export, bag": Exported(Path("b.mcap"), 7858, 2,
                                bag=Ros2Written(imu=5884, mag=1974)).text(),
        "decode": stats.summary(),
        "import": imported.text(),
        "repair": RepairReport(Path("a.mcap"), Path("b.mcap"), 12_345, 1024, 2048, 65_536,
                               False, "cut short").text(),
        "demo": rendered(_summary([UnitOutcome("imu1", 3103, 1358, 1030, 1026, 1001, 41.2,
                                               42.0, "")])),
    }
    bare = {name: BARE.findall(text) for name, text in texts.items()}
    assert not any(bare.values()), (bare, texts)
    assert "wrote 2,094 instants at 100 Hz of 7,858 samples" in texts["export, aligned"]
    assert "wrote 5,884 Imu and 1,974 MagneticField messages" in texts["export, bag"]
    assert "0xC8×1,199" in texts["decode"] and "of 80,400" in texts["decode"]
