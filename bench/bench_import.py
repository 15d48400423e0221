"""Speed and memory of `gx3 import` end to end, run by hand (not part of the tests).

    .venv/bin/python bench/bench_import.py [--records 1000000] [--code 0xCC]

Writes a byte log of 100 Hz records (the timer stepping 625 ticks), then times the
installed `gx3 import LOG -o ARCHIVE` as a subprocess: reading, framing, unwrapping the
timer, encoding the samples and writing the archive. Reports the best of 3 runs and the
child's peak resident memory.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPEATS = 3


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--records", type=int, default=1_000_000)
    parser.add_argument("--code", default="0xCC")
    args = parser.parse_args()
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent))
    if gx3 is None:
        raise SystemExit("gx3 is not installed next to this interpreter")
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "logger.bin"
        # written by a child: this process stays small, so the children it forks (whose
        # peak memory counts what they shared with it) measure gx3 alone
        subprocess.run([sys.executable, "-c", "import sys; from pathlib import Path; "
                        "from bench_codec import stream; Path(sys.argv[1]).write_bytes("
                        "stream(int(sys.argv[2], 0), int(sys.argv[3])))", str(log), args.code,
                        str(args.records)], check=True, cwd=Path(__file__).parent)
        best, peak = float("inf"), 0
        for i in range(REPEATS):
            out = Path(tmp) / f"imported{i}.mcap"
            started = time.perf_counter()
            proc = subprocess.Popen([gx3, "import", str(log), "-u", "u", "--start",
                                     "2026-01-01T00:00:00Z", "-o", str(out)],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            _, status, usage = os.wait4(proc.pid, 0)
            elapsed = time.perf_counter() - started
            if status != 0:
                raise SystemExit(proc.stderr.read().decode() if proc.stderr else "failed")
            best, peak = min(best, elapsed), max(peak, usage.ru_maxrss)
        print(f"gx3 import, {args.records:,} records of {args.code} "
              f"({log.stat().st_size / 1e6:,.0f} MB): best {best:.2f} s "
              f"({args.records / best:,.0f} records/s), peak {peak / 1024:,.0f} MiB, "
              f"archive {out.stat().st_size / 1e6:,.0f} MB; load average "
              f"{os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
