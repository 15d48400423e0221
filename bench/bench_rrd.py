"""`gx3 rrd` of a fleet's day: the default overview and a 10-minute window at full rate, and
what Rerun's viewer needs to open each.

    .venv/bin/python bench/bench_rrd.py [--units 16] [--hours 8] [--rate 100]
                                       [--window-start 14400] [--dir DIR]

Writes (once; kept with --dir) an archive of --units units streaming 0xCC (accel,
ang_rate, mag, M) at --rate for --hours, made in virtual time from the emulator's motion
model (``bridge.sim.fleet_archive``: Info, a status a second, the bring-up, attitude
frames), as `gx3 record` would have. Then, with the load average (other work slows it
all):

- `gx3 rrd ARCHIVE -o overview.rrd` (the default: what it chose and said) and `gx3 rrd
  ARCHIVE -o window.rrd --start S --end S+600` (10 minutes of every unit at full rate),
  as a user runs them: wall seconds, the peak resident memory of the process, the size of
  the recording, and the full-rate size of the whole day at the window's bytes a sample;
- each recording opened in Rerun's headless viewer (a Vulkan driver is needed: on
  Debian, mesa-vulkan-drivers): how much more memory the viewer holds once it has loaded
  it than an empty one, and the smallest of 256 MB, 512 MB, 1 GB, 2 GB, 4 GB and 8 GB
  that `rerun --memory-limit` can be given without the viewer freeing data ("Reached
  memory limit" in its log).

With --picture PNG, the overview's accel tab is also pictured (the Rerun guide's).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from procstat import gx3_measured, load, peak_rss_mb
from rerun.experimental import ViewerClient

from bridge.archive.walk import sample_span
from bridge.fleet.snapshot import headless_viewer, open_recording, render
from bridge.sim.archived import fleet_archive

WINDOW_S = 600
LIMITS = ("256MB", "512MB", "1GB", "2GB", "4GB", "8GB")
#: How long a viewer that has loaded a recording is watched for freeing data.
SETTLE_S = 5.0


def build(path: Path, units: int, hours: float, rate: float) -> None:
    if path.exists():
        print(f"using {path} ({path.stat().st_size / 1e9:.2f} GB)", flush=True)
        return
    start = time.perf_counter()
    shown = [start]

    def progress(seconds: float) -> None:
        if time.perf_counter() - shown[0] >= 30:
            shown[0] = time.perf_counter()
            print(f"  {seconds / 3600:.2f} of {hours:g} h written", flush=True)

    fleet_archive(path, [f"imu{u}" for u in range(1, units + 1)], hours * 3600, rate,
                  progress=progress)
    print(f"wrote {path.name}: {units} units x {hours:g} h at {rate:g} Hz, "
          f"{path.stat().st_size / 1e9:.2f} GB in {time.perf_counter() - start:.0f} s",
          flush=True)


def freed(client: ViewerClient) -> bool:
    """Whether the viewer has said it reached its memory limit and freed data."""
    return any("Reached memory limit" in entry.message for entry in client.get_logs())


def viewer_memory(rrd: Path) -> tuple[float, float]:
    """MiB a headless viewer holds beyond an empty one once it has loaded ``rrd`` (its
    peak), and the seconds it took to load."""
    with headless_viewer(timeout_s=600) as (client, wrapper):
        viewer = _viewer_pid(wrapper.pid)
        empty = peak_rss_mb(viewer)
        start = time.perf_counter()
        open_recording(client, rrd, timeout_s=600)
        loaded = time.perf_counter() - start
        time.sleep(SETTLE_S)
        return peak_rss_mb(viewer) - empty, loaded


def _viewer_pid(wrapper: int) -> int:
    """The viewer the ``rerun`` wrapper started (the wrapper itself if it is the viewer)."""
    import psutil

    children = psutil.Process(wrapper).children(recursive=True)
    return children[-1].pid if children else wrapper


def smallest_limit(rrd: Path) -> str | None:
    """The smallest of LIMITS a viewer opens ``rrd`` within without freeing data."""
    for limit in LIMITS:
        with headless_viewer(timeout_s=600, memory_limit=limit) as (client, _):
            open_recording(client, rrd, timeout_s=600)
            time.sleep(SETTLE_S)
            if not freed(client):
                return limit
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--window-start", type=float, default=4 * 3600.0,
                        help="seconds from the first sample")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: tmp)")
    parser.add_argument("--no-viewer", action="store_true", help="skip the viewer's memory")
    parser.add_argument("--picture", type=Path, metavar="PNG",
                        help="also picture the overview's accel tab here")
    args = parser.parse_args()
    workdir = args.dir or Path(tempfile.mkdtemp(prefix="bench_rrd_"))
    workdir.mkdir(parents=True, exist_ok=True)
    archive = workdir / f"fleet-{args.units}x{args.hours:g}h-{args.rate:g}hz.mcap"
    build(archive, args.units, args.hours, args.rate)
    samples = sum(sample_span(archive).counts.values())
    print(f"{samples:,} samples; {load()}", flush=True)
    start = args.window_start
    runs = {"overview": ["-o", workdir / "overview.rrd"],
            "window": ["-o", workdir / "window.rrd", "--start", f"{start:g}",
                       "--end", f"{start + WINDOW_S:g}"]}
    sizes: dict[str, float] = {}
    for name, options in runs.items():
        elapsed, peak, said = gx3_measured("rrd", archive, *options, "--force")
        rrd = Path(options[1])
        sizes[name] = rrd.stat().st_size / 1e6
        print(f"{name}: {elapsed:.0f} s, peak {peak:.0f} MiB, {sizes[name]:,.0f} MB "
              f"({load()})\n  " + "\n  ".join(said.strip().splitlines()), flush=True)
    per_sample = sizes["window"] * 1e6 / (args.units * args.rate * WINDOW_S)
    print(f"full rate: {per_sample:.0f} bytes a sample, {samples * per_sample / 1e9:,.1f} GB "
          "for the whole archive", flush=True)
    if args.picture is not None:
        render(workdir / "overview.rrd", args.picture, tab="accel [g]", timeout_s=600)
        print(f"pictured the overview: {args.picture}", flush=True)
    if args.no_viewer:
        return
    for name in runs:
        rrd = workdir / f"{name}.rrd"
        held, loaded = viewer_memory(rrd)
        print(f"viewer, {name}: loaded in {loaded:.0f} s, {held:,.0f} MiB more than an empty "
              f"viewer; opens within --memory-limit {smallest_limit(rrd) or 'none tried'}",
              flush=True)


if __name__ == "__main__":
    main()
