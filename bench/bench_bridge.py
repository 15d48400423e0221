"""What one unit at 1,000 Hz of 0xCC (79 B at 921,600 baud) costs, side by side in one run.

On the same emulated stream (one emulated unit on a pty), one after the other:

- a C ``select`` + ``read`` loop (compiled with gcc into a temporary folder; skipped,
  and said so, when there is no gcc): the least any process can spend on the stream;
- the same loop in Python (``select`` + ``os.read``);
- that Python loop with one plain Zenoh put per record (an ImuSample-sized payload
  and its CRC-32 attachment): the least a Python bridge can spend;
- that loop coalescing reads as the bridge does at each latency budget above 1 ms
  (after a read it sleeps so that bytes gather for the budget less 1 ms): the floor
  for that budget;
- that loop, at 1 ms and at the largest budget, putting through an advanced publisher
  declared as the bridge declares its imu key: what the publisher kind costs;
- ``gx3 bridge`` at ``--max-latency-ms`` 1, 2 and 5; where the compiled core
  (``bridge/_records.c``) is built, each also without it (``GX3_NATIVE=0``): what it gives;
  with ``--metrics``, each serving its health to Prometheus (the latency histogram
  observes one read in 16).

For each: its process's CPU (user + system time over wall time, % of one core), the
same per record, the latency from the receive stamp of the read that completed a
record to a subscriber callback in this process (p50, p99; both on this machine's
clock), whether every sample the unit sent was delivered, and the CPU as a ratio to
the Python loop with puts and to the floor of its budget (the plain-put loop
coalescing as it does). The bridge's CPU is also given by thread.

    python bench/bench_bridge.py --seconds 10
    PYTHONPATH=OTHER_TREE python bench/bench_bridge.py --budgets default  # another version
    python bench/bench_bridge.py --budgets 1 --metrics  # with its health served
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zenoh
from procstat import cpu_seconds, thread_cpu_seconds
from zenoh.ext import AdvancedPublisher

from bridge import _native as native
from bridge.bus.codec import layout
from bridge.fleet.loopback import free_port, interrupt, loopback_config
from bridge.protocol.table import REPLIES, Flag
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

CODE = 0xCC
RATE_HZ = 1000
START = bytes([0xC4, 0xC1, 0x29, CODE])  # continuous mode, 0xCC
STOP = bytes([0xFA, 0x75, 0xB4])
KEY = "gx3/bench/imu"
PURE = ", pure Python"
#: A loop says "ready" once it has the port; SIGUSR1 then asks it for the bytes it has read
#: so far (one line on stdout each).
C_LOOP = r"""
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <sys/file.h>
#include <sys/select.h>
#include <termios.h>
#include <unistd.h>

static volatile sig_atomic_t stop = 0, ask = 0;
static void on_int(int s) { (void)s; stop = 1; }
static void on_usr1(int s) { (void)s; ask = 1; }

int main(int argc, char **argv) {
    if (argc < 2) return 2;
    int fd = open(argv[1], O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) { perror("open"); return 1; }
    if (flock(fd, LOCK_EX | LOCK_NB) < 0) { perror("flock"); return 1; }  /* as pyserial */
    struct termios t;
    tcgetattr(fd, &t);
    cfmakeraw(&t);  /* and the rest as pyserial sets a port */
    t.c_cflag |= CLOCAL | CREAD;
    t.c_cflag &= ~(HUPCL | CRTSCTS);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    cfsetispeed(&t, B921600);  /* the emulated line checks the host's rate */
    cfsetospeed(&t, B921600);
    tcsetattr(fd, TCSANOW, &t);
    struct sigaction a = {0}, u = {0};
    a.sa_handler = on_int;
    u.sa_handler = on_usr1;
    sigaction(SIGINT, &a, NULL);
    sigaction(SIGUSR1, &u, NULL);
    const unsigned char start[] = {0xC4, 0xC1, 0x29, 0xCC}, halt[] = {0xFA, 0x75, 0xB4};
    write(fd, start, sizeof start);
    printf("ready\n");
    fflush(stdout);
    unsigned long long total = 0;
    unsigned char buf[65536];
    while (!stop) {
        if (ask) { ask = 0; printf("%llu\n", total); fflush(stdout); }
        fd_set r;
        FD_ZERO(&r);
        FD_SET(fd, &r);
        struct timeval tv = {0, 50000};
        if (select(fd + 1, &r, NULL, NULL, &tv) > 0) {
            ssize_t n = read(fd, buf, sizeof buf);
            if (n > 0) total += (unsigned long long)n;
        }
    }
    write(fd, halt, sizeof halt);
    close(fd);
    return 0;
}
"""


def loop(kind: str, budget_ms: str, port: str, config: str) -> None:
    """The Python loops, as their own process, until SIGINT: ``read`` reads only, ``put``
    puts one payload per whole record: an ImuSample's size, starting with the receive
    time and the record's number (int64 LE each), with its CRC-32 as attachment;
    ``advanced`` puts the same through the bridge's kind of publisher. Above a 1 ms
    budget, bytes gather for the budget less 1 ms after each read, as in the bridge."""
    from bridge.bus.keys import ENCODINGS
    from bridge.bus.publish import CACHE_SAMPLES, declare_data_publisher
    from bridge.bus.session import open_session
    from bridge.device.port import Port
    from bridge.unit.pipeline import PUBLISH_RESERVE_S

    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    asked = threading.Event()
    signal.signal(signal.SIGUSR1, lambda *_: asked.set())
    size = REPLIES[CODE].length
    padding = bytes(layout(CODE, "bench").size - 16)
    hold_s = max(0.0, float(budget_ms) / 1000 - PUBLISH_RESERVE_S)
    total = held = number = 0
    last = 0.0
    with contextlib.ExitStack() as stack:  # no Zenoh at all for the read-only loop
        pub: zenoh.Publisher | AdvancedPublisher | None = None
        if kind != "read":
            session = stack.enter_context(open_session(config))
            pub = session.declare_publisher(KEY) if kind == "put" else declare_data_publisher(
                session, KEY, ENCODINGS["imu"], CACHE_SAMPLES)
            stack.callback(pub.undeclare)
        link = Port.open(port, 921_600)
        fd = link.raw.fileno()
        link.write(START)
        print("ready", flush=True)
        while not stop.is_set():
            if asked.is_set():
                asked.clear()
                print(total, flush=True)
            pause = last + hold_s - time.monotonic()
            if pause > 0:
                time.sleep(pause)
            if select.select([fd], [], [], 0.05)[0]:
                data = os.read(fd, 1 << 16)
                last = time.monotonic()
                total += len(data)
                if pub is not None:
                    held += len(data)
                    rx = time.time_ns()
                    for _ in range(held // size):
                        payload = rx.to_bytes(8, "little") + number.to_bytes(8, "little") \
                            + padding
                        pub.put(payload, attachment=zlib.crc32(payload).to_bytes(4, "little"))
                        number += 1
                    held %= size
        link.write(STOP)
        link.close()


@dataclass
class Row:
    name: str
    cpu_pct: float = float("nan")
    budget_ms: float = 1.0  # the latency budget it reads with (coalescing above 1 ms)
    records: int = 0  # in the measured window
    p50_ms: float | None = None
    p99_ms: float | None = None
    delivered: str = "n/a"
    threads: dict[str, float] = field(default_factory=dict)

    @property
    def us_per_record(self) -> float:
        return 1e4 * self.cpu_pct / RATE_HZ


class Subscriber:
    """Receive time → callback latency and what arrived, of the samples on ``KEY``."""

    def __init__(self, session: zenoh.Session, floor: bool) -> None:
        self.floor = floor
        fields = layout(CODE, "bench").dtype.fields
        assert fields is not None
        # read in place, not parsed: this process also runs the emulated unit
        self.rx_at, self.ticks_at = fields["rx_ns"][1], fields["ticks"][1]
        self.lock = threading.Lock()
        self.latency: list[int] = []
        self.ids: list[int] = []
        self.sub = session.declare_subscriber(KEY, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        payload = sample.payload.to_bytes()
        if self.floor:
            rx, ident = int.from_bytes(payload[:8], "little"), int.from_bytes(payload[8:16],
                                                                              "little")
        else:
            rx = int.from_bytes(payload[self.rx_at : self.rx_at + 8], "little")
            ident = int.from_bytes(payload[self.ticks_at : self.ticks_at + 8], "little")
        with self.lock:
            self.latency.append(now - rx)
            self.ids.append(ident)

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        with self.lock:
            out = np.array(self.latency), np.array(self.ids)
            self.latency.clear()
            self.ids.clear()
        return out

    def count(self) -> int:
        with self.lock:
            return len(self.ids)


def measure(name: str, command: list[str], seconds: float, session: zenoh.Session | None,
            kind: str, budget_ms: float = 1.0, env: dict[str, str] | None = None) -> Row:
    """Run ``command`` on the stream; its CPU and deliveries over ``seconds``."""
    row = Row(name, budget_ms=budget_ms)
    sub = Subscriber(session, kind == "put") if session is not None else None
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, text=True,
                            env=None if env is None else {**os.environ, **env})
    try:
        deadline = time.monotonic() + 30
        if sub is not None:  # warm: the unit streams and the subscriber hears it
            while sub.count() < 1000 and time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.1)
        else:  # the loop has its port and its signal handlers, then streams a while
            ready(proc)
            time.sleep(1.5)
        if proc.poll() is not None:
            raise SystemExit(f"{name}: exited with {proc.returncode} before the measurement")
        read0 = asked(proc) if sub is None else 0
        if sub is not None:
            sub.take()
        cpu0, wall0, threads0 = cpu_seconds(proc.pid), time.monotonic(), thread_cpu_seconds(
            proc.pid)
        time.sleep(seconds)
        cpu1, wall1, threads1 = cpu_seconds(proc.pid), time.monotonic(), thread_cpu_seconds(
            proc.pid)
        read1 = asked(proc) if sub is None else 0
        time.sleep(0.3)  # the samples read before the window closed reach the subscriber
        wall = wall1 - wall0
        row.cpu_pct = 100 * (cpu1 - cpu0) / wall
        row.threads = {k: 100 * (v - threads0.get(k, 0.0)) / wall for k, v in threads1.items()}
        if sub is None:
            row.records = (read1 - read0) // REPLIES[CODE].length
            row.delivered = "yes" if row.records >= 0.99 * RATE_HZ * wall else \
                f"no ({row.records} read)"
        else:
            latency, ids = sub.take()
            sub.sub.undeclare()
            row.records = len(ids)
            steps = np.diff(ids) if kind == "put" else np.round(np.diff(ids) / 62.5)
            missing = int(steps.sum() - len(steps)) if len(ids) else -1
            enough = len(ids) >= 0.99 * RATE_HZ * wall
            row.delivered = "yes" if missing == 0 and enough else \
                f"no ({missing} missing of {len(ids)})"
            if len(latency):
                row.p50_ms = float(np.percentile(latency, 50) / 1e6)
                row.p99_ms = float(np.percentile(latency, 99) / 1e6)
    finally:
        interrupt([proc], timeout=30)
        if proc.stdout is not None:
            proc.stdout.close()
    return row


def ready(proc: subprocess.Popen[str]) -> None:
    """Wait for a loop's first line: it has opened the port."""
    assert proc.stdout is not None
    if not select.select([proc.stdout], [], [], 30.0)[0] or proc.stdout.readline() != "ready\n":
        raise SystemExit(f"a read loop did not start (exit status {proc.poll()}; another "
                         "program holding the pty?)")


def asked(proc: subprocess.Popen[str]) -> int:
    """A loop's bytes read so far."""
    assert proc.stdout is not None
    proc.send_signal(signal.SIGUSR1)
    answered, _, _ = select.select([proc.stdout], [], [], 5.0)
    line = proc.stdout.readline() if answered else ""
    if not line:
        raise SystemExit(f"a read loop did not answer SIGUSR1 (exit status {proc.poll()}; "
                         "another program holding the pty?)")
    return int(line)


def compile_c(folder: Path) -> Path | None:
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    source, binary = folder / "loop.c", folder / "loop"
    source.write_text(C_LOOP)
    subprocess.run([gcc, "-O2", "-o", str(binary), str(source)], check=True)
    return binary


def table(rows: list[Row]) -> str:
    base = next((r.cpu_pct for r in rows if r.name.endswith("+ put")), float("nan"))
    #: the floor of each budget: the plain-put loop coalescing as a bridge with that budget
    floors = {r.budget_ms: r.cpu_pct for r in rows if r.name.startswith("Python")
              and " put" in r.name and "advanced" not in r.name}
    lines = ["| loop on the same pty stream | % of a core | µs per record | rx → subscriber "
             "p50 / p99 ms | every sample | × Python select+read+put | × its budget's floor |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.cpu_pct != r.cpu_pct:  # skipped
            lines.append(f"| {r.name} | {r.delivered} | | | | | |")
            continue
        latency = "–" if r.p50_ms is None or r.p99_ms is None else \
            f"{r.p50_ms:.3f} / {r.p99_ms:.3f}"
        floor = floors.get(r.budget_ms) if " put" in r.name or r.name.startswith("gx3") \
            else None
        lines.append(f"| {r.name} | {r.cpu_pct:.1f} | {r.us_per_record:.0f} | {latency} | "
                     f"{r.delivered} | {r.cpu_pct / base:.2f} | "
                     f"{'–' if floor is None else f'{r.cpu_pct / floor:.2f}'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="measured seconds per row (each row warms up first)")
    parser.add_argument("--budgets", default="1,2,5",
                        help="gx3 bridge --max-latency-ms values, comma-separated; 'default' "
                             "runs it without the option (also a bridge from before it)")
    parser.add_argument("--metrics", action="store_true",
                        help="gx3 bridge also serves --metrics on a free loopback port")
    parser.add_argument("--loop-child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.loop_child:
        loop(*args.loop_child)
        return
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or "gx3"
    unit = UnitConfig(serial="BENCH", motion=MotionConfig(seed=1), stored=Stored(
        mode_preset=2, continuous_preset=CODE, baud=921_600,
        sampling=Sampling(decimation=1, flags=int(Flag.CONING_SCULLING))))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    scouting = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
    rows: list[Row] = []
    with tempfile.TemporaryDirectory() as tmp, Simulator([unit], "pty") as sim:
        port = sim.endpoints[0]
        cfg = loopback_config(Path(tmp, "bridge.json5"), listen=[endpoint])
        client = zenoh.Config.from_json5(json.dumps({
            "mode": "peer", "connect": {"endpoints": [endpoint]}, "scouting": scouting}))
        binary = compile_c(Path(tmp))
        if binary is None:
            rows.append(Row("C select + read", delivered="skipped: no gcc on this machine"))
        else:
            rows.append(measure("C select + read", [str(binary), port], args.seconds, None,
                                "read"))
        me = [sys.executable, __file__, "--loop-child"]
        rows.append(measure("Python select + os.read", [*me, "read", "1", port, str(cfg)],
                            args.seconds, None, "read"))
        budgets = args.budgets.split(",")
        floors = sorted({1.0, *(float(b) for b in budgets if b != "default")})
        loops = [("put", ms) for ms in floors] + [("advanced", ms) for ms in
                                                  sorted({floors[0], floors[-1]})]
        with zenoh.open(client) as session:
            for kind, ms in loops:
                name = "Python select + os.read + " + ("put" if kind == "put" else
                                                       "advanced put")
                if ms > 1:
                    name += f", {ms:g} ms budget"
                rows.append(measure(name, [*me, kind, str(ms), port, str(cfg)], args.seconds,
                                    session, "put", ms))
            cores = [False] if native.records is None else [True, False]
            for budget in budgets:
                option = [] if budget == "default" else ["--max-latency-ms", budget]
                served = ["--metrics", f"127.0.0.1:{free_port()}"] if args.metrics else []
                command = [gx3, "bridge", "--port", port, "--baud", "921600", "--unit", "bench",
                           "--zenoh-config", str(cfg), "--quiet", *option, *served]
                for core in cores:
                    name = " ".join(["gx3 bridge", *option, *served[:1]]) + (
                        "" if core else PURE)
                    rows.append(measure(name, command, args.seconds, session, "bridge",
                                        1.0 if budget == "default" else float(budget),
                                        None if core else {"GX3_NATIVE": "0"}))
    print(f"0x{CODE:02X} at {RATE_HZ:,} Hz, 921,600 baud, pty; {args.seconds:g} s a row")
    print(table(rows))
    for r in rows:
        if r.name.startswith("gx3"):
            busy = sorted(((t, n) for n, t in r.threads.items() if t >= 0.05), reverse=True)
            print(f"{r.name}, by thread: " + ", ".join(f"{n} {t:.1f} %" for t, n in busy))


if __name__ == "__main__":
    main()
