"""`gx3 allan` on emulated still units at the rates and filter widths users record at: the
noise densities it reads, over the sensor's.

    .venv/bin/python bench/bench_allan_accuracy.py [--minutes 25] [--dir DIR]
                                                   [--before CHECKOUT]

Writes (once; kept with --dir) an archive per case of one still unit streaming 0xC2, made
in virtual time from the emulator's noise model through the unit's filter (the moving
average of M calculation cycles, every D-th sent), with a sensor noise density of
2e-3 m/s²/√Hz and 1e-4 rad/s/√Hz and random walks of 2e-4 and 1e-5; runs `gx3 allan`
on each as a user would (`python -m bridge allan`) and prints each axis's density over
the sensor's. With --before, also runs the gx3 of another checkout (its directory put
first on PYTHONPATH) on the same archives, for the table of a change.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from ruamel.yaml import YAML

from bridge.archive.writer import ArchiveWriter
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig, SignalChain

#: (output rate Hz, filter width M): the issue's rows, then D > M.
CASES = ((1000, 15), (500, 32), (200, 15), (250, 8), (100, 15), (100, 4), (50, 15))
TRUTH = {"accelerometer": 2e-3, "gyroscope": 1e-4}
STILL = MotionConfig(seed=11, static=True, accelerometer_noise_density=2e-3,
                     accelerometer_random_walk=2e-4, gyroscope_noise_density=1e-4,
                     gyroscope_random_walk=1e-5)


def archive(path: Path, rate: int, width: int, minutes: float) -> None:
    if path.exists():
        return
    times = np.arange(round(minutes * 60 * rate)) / rate
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "imu1", Motion(STILL), times, 1 / rate,
                        chain=SignalChain(width, 17, True))


def read(path: Path, out: Path, pythonpath: Path | None) -> dict[str, list[float]]:
    """Each sensor's densities per axis over the truth, as `gx3 allan` wrote them."""
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    done = subprocess.run([sys.executable, "-m", "bridge", "allan", str(path), "-o", str(out),
                           "--force"], capture_output=True, text=True, env=env)
    if done.returncode:
        raise SystemExit(f"gx3 allan failed on {path.name}: {done.stderr.strip()}")
    found = YAML(typ="safe").load(out.read_text())
    if "gx3_allan" not in found or "accelerometer" not in found["gx3_allan"]:
        return {s: [found[f"{s}_noise_density"] / t] for s, t in TRUTH.items()}
    return {s: [v / t for v in found["gx3_allan"][s]["noise_density"]]
            for s, t in TRUTH.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=25.0)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: tmp)")
    parser.add_argument("--before", type=Path, default=None,
                        help="a checkout whose gx3 allan to run on the same archives too")
    args = parser.parse_args()
    workdir = args.dir or Path(tempfile.mkdtemp(prefix="bench_allan_accuracy_"))
    workdir.mkdir(parents=True, exist_ok=True)
    print(f"{args.minutes:g} min of a still unit per case; density found / the sensor's, "
          "each axis (x, y, z)")
    for rate, width in CASES:
        path = workdir / f"still_{rate}hz_m{width}_{args.minutes:g}min.mcap"
        archive(path, rate, width, args.minutes)
        rows = [("this", read(path, workdir / "imu.yaml", None))]
        if args.before is not None:
            rows.append(("before", read(path, workdir / "imu_before.yaml", args.before)))
        for name, found in rows:
            shown = "; ".join(f"{sensor} {', '.join(f'{r:.3f}' for r in ratios)}"
                              for sensor, ratios in found.items())
            print(f"{rate:>5} Hz, M {width:>2} (D {1000 // rate:>2}), {name:>6}: {shown}",
                  flush=True)


if __name__ == "__main__":
    main()
