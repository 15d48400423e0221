"""The emulated unit in virtual time: rates, pacing, skipping, clocks, memory, physics."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.protocol.codec import Batch, encode_command
from bridge.protocol.convert import m_to_euler, m_to_quaternion, quaternion_to_m
from bridge.protocol.framer import Framer
from bridge.protocol.table import DATA_CODES, REPLIES, TICKS_PER_SECOND, Flag
from bridge.sim.faults import FaultConfig, Faults, reframe
from bridge.sim.motion import MotionConfig
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import SimUnit, TruthLog, UnitConfig

SETTINGS = {"filter_width": 15, "mag_filter_width": 17, "up_compensation": 10,
            "north_compensation": 10}


class Host:
    """Drives a unit in virtual time, as a transport would, and frames what it says."""

    def __init__(self, unit: SimUnit, t: float = 0.0) -> None:
        self.unit, self.t = unit, t

    def run(self, seconds: float, step: float = 0.0005) -> bytes:
        out = bytearray()
        end = self.t + seconds
        while self.t < end:
            self.t = min(end, self.t + step)
            out += self.unit.poll(self.t)
        return bytes(out)

    def send(self, name: str, settle: float = 0.01, /, **params: Any) -> bytes:
        self.unit.receive(encode_command(name, **params), self.t)
        return self.run(settle)

    def records(self, seconds: float, *codes: int) -> list[Batch]:
        framer = Framer(codes or DATA_CODES, little_endian=self.unit.little_endian)
        return framer.feed(self.run(seconds)) + framer.flush()

    def stream(self, code: int, decimation: int, baud: int = 115_200, flags: int = 0) -> None:
        if baud != self.unit.baud:
            self.send("comms_settings", port=1, function=1, baud=baud, config=2)
        self.send("sampling_settings", function=1, decimation=decimation, flags=flags, **SETTINGS)
        self.send("set_continuous", command=code)


def unit(now: float = 0.0, **kw: Any) -> Host:
    motion = kw.pop("motion", MotionConfig(seed=3))
    u = SimUnit(UnitConfig(motion=motion, **kw), now=now, wall_ns=1_000_000_000_000)
    host = Host(u, now)
    host.run(0.2)
    return host


def one(batches: list[Batch], code: int) -> Batch:
    found = [b for b in batches if b.code == code]
    assert found, f"no 0x{code:02X} records in {[hex(b.code) for b in batches]}"
    return Batch.concatenate(found)


@pytest.mark.parametrize("uptime_s", [0.0, 20_000.0, 5e6], ids=["boot", "5h", "2 months"])
@pytest.mark.parametrize(("decimation", "baud"), [(10, 115_200), (4, 115_200), (2, 460_800),
                                                  (1, 921_600)])
def test_continuous_rate_and_timer_spacing(decimation: int, baud: int, uptime_s: float) -> None:
    """Host times are monotonic seconds since boot: a host up for hours or months has
    coarser floats, and no record may be lost to their rounding."""
    host = unit(now=uptime_s)
    host.stream(0xC2, decimation, baud)
    host.run(0.05)
    recs = one(host.records(1.0, 0xC2), 0xC2)
    assert len(recs) == pytest.approx(1000 / decimation, abs=2)
    steps = np.diff(recs["timer"].astype(np.float64))
    assert steps.mean() == pytest.approx(decimation * TICKS_PER_SECOND / 1000, rel=1e-3)
    assert np.abs(steps - decimation * 62.5).max() <= 0.5
    assert host.unit.records_skipped == 0


def test_a_slow_line_skips_records_and_the_timer_shows_the_gap() -> None:
    host = unit()
    host.stream(0xCC, 1, 115_200)
    recs = one(host.records(1.0, 0xCC), 0xCC)
    per_record = 79 * 10 / 115_200
    assert len(recs) == pytest.approx(1 / (np.ceil(per_record * 1000) / 1000), rel=0.02)
    steps = np.diff(recs["timer"].astype(np.int64))
    assert steps.min() > 62.5 * per_record * 1000 - 1
    assert host.unit.records_skipped > 800
    assert host.unit.records_sent + host.unit.records_skipped >= 990


def test_bytes_leave_at_the_line_rate() -> None:
    host = unit()
    host.stream(0xC8, 10, 115_200)
    host.run(0.05)
    arrivals = [len(host.run(0.0001, step=0.0001)) for _ in range(2000)]
    assert sum(arrivals) == pytest.approx(67 * 20, abs=67)
    assert max(arrivals) <= 2


def test_timer_rollover_is_crossed() -> None:
    host = unit(timer_start=0xFFFF_FFFF - TICKS_PER_SECOND // 2)
    host.stream(0xC2, 10)
    timers = one(host.records(1.5, 0xC2), 0xC2)["timer"].astype(np.int64)
    wraps = np.flatnonzero(np.diff(timers) < 0)
    assert len(wraps) == 1
    unwrapped = timers + (np.arange(len(timers)) > wraps[0]) * (1 << 32)
    assert np.allclose(np.diff(unwrapped), 625, atol=1)


@pytest.mark.parametrize("ppm", [-100.0, 0.0, 250.0])
def test_clock_error_shows_in_the_timer(ppm: float) -> None:
    host = unit(clock_ppm=ppm)
    host.stream(0xC2, 100)
    host.run(0.05)
    recs = one(host.records(20.0, 0xC2), 0xC2)
    ticks = np.diff(recs["timer"][[0, -1]].astype(np.int64))[0]
    host_s = len(recs) and (recs["timer"].size - 1) * 0.1 / (1 + ppm * 1e-6)
    sampled = host.unit.truth.arrays()["time_ns"][-len(recs):]
    assert (sampled[-1] - sampled[0]) / 1e9 == pytest.approx(host_s, abs=1e-6)
    assert ticks / TICKS_PER_SECOND / host_s == pytest.approx(1 + ppm * 1e-6, abs=2e-7)


def test_mode_reply_comes_before_the_first_record() -> None:
    host = unit(stored=Stored(continuous_preset=0xC2))
    framer = Framer({0xD4, 0xC2})
    batches = framer.feed(host.send("mode", 0.1, mode=2))
    assert batches[0].code == 0xD4 and batches[0]["mode"][0] == 2
    assert batches[1].code == 0xC2 and len(batches[1]) >= 9


def test_factory_preset_zero_makes_continuous_mode_do_nothing() -> None:
    host = unit()
    assert host.send("mode", 0.2, mode=2) == bytes((0xD4, 0x01, 0x00, 0xD5))


def test_power_on_in_continuous_preset_streams_without_a_mode_reply() -> None:
    host = unit(stored=Stored(mode_preset=2, continuous_preset=0xCE))
    batches = host.records(0.5, 0xCE, 0xD4)
    assert [b.code for b in batches] == [0xCE]


def test_idle_mode_returns_nan_and_suppression_zeros() -> None:
    host = unit()
    host.send("mode", mode=3)
    host.unit.receive(bytes((0xC8,)), host.t)
    rec = one(host.records(0.01, 0xC8), 0xC8)
    assert np.isnan(rec["accel"]).all() and np.isnan(rec["m"]).all()
    host.send("sampling_settings", function=1, decimation=10,
              flags=int(Flag.ORIENTATION | Flag.SUPPRESS_NAN), **SETTINGS)
    host.unit.receive(bytes((0xC2,)), host.t)
    rec = one(host.records(0.01, 0xC2), 0xC2)
    assert (rec["accel"] == 0).all()


def test_little_endian_flag_swaps_floats_only() -> None:
    host = unit()
    host.stream(0xC2, 10, flags=int(Flag.LITTLE_ENDIAN_FLOATS))
    raw = host.run(0.2)
    start = raw.index(bytes((0xC2,)), 8)
    rec = raw[start : start + 31]
    accel_le = np.frombuffer(rec[1:13], "<f4")
    assert np.linalg.norm(accel_le) == pytest.approx(1.0, abs=0.5)
    timer = int.from_bytes(rec[25:29], "big")
    assert sum(rec[:29]) & 0xFFFF == int.from_bytes(rec[29:31], "big")
    assert timer in host.unit.truth.arrays()["timer"]


def test_sleep_wakes_on_any_byte_after_the_settling_time() -> None:
    host = unit()
    host.send("mode", mode=4)
    assert host.send("firmware_version", 0.05) == b""
    host.run(0.09)
    reply = host.send("firmware_version", 0.01)
    assert reply[:1] == bytes((0xE9,)) and len(reply) == 7


def test_deep_sleep_wake_restarts_the_timer() -> None:
    host = unit(timer_start=10_000_000)
    host.send("mode", mode=5)
    host.unit.receive(b"\x00", host.t)
    host.run(0.2)
    reply = host.send("timer", function=0, value=0)
    assert int.from_bytes(reply[1:5], "big") < 0.3 * TICKS_PER_SECOND


def test_nonvolatile_state_survives_reset_and_restart(tmp_path: Path) -> None:
    state = tmp_path / "unit.json"
    host = unit(state_file=state)
    host.send("sampling_settings", function=2, decimation=20, flags=3, **SETTINGS)
    host.send("mode_preset", mode_preset=3)
    host.send("continuous_preset", continuous_preset=0xCB)
    host.send("write_gyro_bias", gyro_bias=[0.01, 0.02, 0.03])
    host.send("transfer_to_nonvolatile", quantity=2)
    host.send("write_accel_bias", accel_bias=[0.5, 0.5, 0.5])
    host.send("write_eeprom", address=0x0401, value=0xBEEF)
    host.send("comms_settings", port=1, function=2, baud=230_400, config=2)
    host.send("sampling_settings", function=1, decimation=50, flags=3, **SETTINGS)
    host.send("device_reset", 0.2)
    u = host.unit
    assert (u.sampling.decimation, u.mode, u.baud) == (20, 3, 230_400)
    assert u.accel_bias.tolist() == [0, 0, 0]
    assert u.gyro_bias.tolist() == pytest.approx([0.01, 0.02, 0.03])
    again = SimUnit(UnitConfig(state_file=state), now=0.0)
    assert again.stored == u.stored
    assert again.stored.word(0x0401) == 0xBEEF and again.stored.continuous_preset == 0xCB


def test_reset_drops_commands_sent_while_booting() -> None:
    host = unit()
    host.unit.receive(encode_command("device_reset"), host.t)
    host.run(0.002)
    assert host.send("firmware_version", 0.05) == b""
    host.run(0.1)
    assert len(host.send("firmware_version", 0.01)) == 7


def test_commands_are_answered_one_per_cycle() -> None:
    host = unit()
    burst = b"".join(encode_command("firmware_version") for _ in range(5))
    host.unit.receive(burst, host.t)
    received, starts = 0, []
    for _ in range(200):
        got = len(host.run(0.0001, step=0.0001))
        if got and received % 7 == 0:
            starts.append(host.t)
        received += got
    assert received == 35
    assert np.diff(starts).min() >= 0.001 - 2e-4


def test_orientation_on_limits_the_rate_to_500_hz() -> None:
    host = unit()
    reply = host.send("sampling_settings", function=1, decimation=1,
                      flags=int(Flag.ORIENTATION), **SETTINGS)
    assert int.from_bytes(reply[1:3], "big") == 2


def test_quaternion_needs_its_flag() -> None:
    host = unit()
    host.unit.receive(bytes((0xDF,)), host.t)
    assert np.isnan(one(host.records(0.01, 0xDF), 0xDF)["quaternion"]).all()
    host.send("sampling_settings", function=1, decimation=10,
              flags=int(Flag.ORIENTATION | Flag.QUATERNION), **SETTINGS)
    host.unit.receive(bytes((0xDF,)), host.t)
    q = one(host.records(0.01, 0xDF), 0xDF)["quaternion"][0]
    assert np.linalg.norm(q) == pytest.approx(1, abs=1e-6) and q[0] >= 0


def test_streamed_records_match_the_ground_truth_attitude() -> None:
    host = unit()
    host.stream(0xCC, 10, flags=int(Flag.ORIENTATION))
    recs = one(host.records(2.0, 0xCC), 0xCC)
    truth = host.unit.truth.arrays()
    index = {int(timer): i for i, timer in enumerate(truth["timer"])}
    m_true = quaternion_to_m(truth["quaternion"][[index[int(k)] for k in recs["timer"]]])
    assert np.abs(recs["m"] - m_true).max() < 1e-6


def test_emulated_records_are_physically_consistent() -> None:
    """What a user integrates from the unit's own records agrees with its attitude."""
    host = unit()
    host.stream(0xC8, 10, flags=int(Flag.ORIENTATION))
    recs = one(host.records(3.0, 0xC8), 0xC8)
    m = recs["m"].astype(np.float64)
    assert np.abs(m @ np.swapaxes(m, 1, 2) - np.eye(3)).max() < 1e-6
    assert np.allclose(np.linalg.det(m), 1, atol=1e-6)
    assert np.allclose(quaternion_to_m(m_to_quaternion(m)), m, atol=1e-6)
    assert m_to_euler(m).shape == (len(m), 3)
    rate = recs["ang_rate"].astype(np.float64)
    dt = 0.01
    current = m[0]
    for i in range(1, len(m)):
        w = 0.5 * (rate[i - 1] + rate[i]) * dt
        skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        current = (np.eye(3) - skew + skew @ skew / 2) @ current
    angle = np.arccos(np.clip((np.trace(current @ m[-1].T) - 1) / 2, -1, 1))
    assert angle < 2e-3


def test_a_static_unit_reads_one_g() -> None:
    host = unit(motion=MotionConfig(seed=5, static=True))
    host.stream(0xCB, 10)
    recs = one(host.records(0.5, 0xCB), 0xCB)
    assert np.allclose(np.linalg.norm(recs["accel"], axis=1), 1.0, atol=1e-6)
    assert np.allclose(recs["ang_rate"], 0, atol=1e-9)


def test_capture_gyro_bias_finds_the_true_bias_of_a_still_unit() -> None:
    bias = (0.004, -0.002, 0.001)
    host = unit(motion=MotionConfig(static=True, gyro_bias_rad_s=bias))
    host.unit.receive(encode_command("capture_gyro_bias", sampling_time_ms=500), host.t)
    assert host.run(0.45) == b""
    batches = Framer({0xCD}).feed(host.run(0.1))
    assert batches[0]["gyro_bias"][0] == pytest.approx(bias, abs=1e-7)
    host.unit.receive(bytes((0xC2,)), host.t)
    assert np.abs(one(host.records(0.01, 0xC2), 0xC2)["ang_rate"]).max() < 1e-7


RATES = (9600, 19200, 57600, 115_200, 230_400, 460_800, 921_600)


def falling_edges(data: bytes) -> int:
    """Falling edges on an idle-high line carrying ``data`` as 8N1 frames."""
    bits = np.unpackbits(np.frombuffer(data, np.uint8)[:, None], axis=1, bitorder="little")
    line = np.concatenate([np.ones((len(data), 1), int), np.zeros((len(data), 1), int), bits],
                          axis=1).ravel()
    return int(((line[:-1] == 1) & (line[1:] == 0)).sum())


@pytest.mark.parametrize("read", RATES)
@pytest.mark.parametrize("sent", RATES)
def test_reframe_at_any_pair_of_rates_ends_and_stays_a_uart(sent: int, read: int) -> None:
    data = bytes(range(256)) * 4 + bytes(50) + b"\xff" * 50
    out = reframe(data, sent, read)
    ratio = sent / read
    assert len(out) <= falling_edges(data)  # every byte needs a start bit's edge
    assert len(out) <= len(data) * 10 / (9.5 * ratio) + 1  # and 9.5 of its own bits
    if sent == read:
        assert out == data
    if ratio <= 1 / 9.5:  # every sent bit outlasts a whole received byte
        assert out == bytes(falling_edges(data))


def test_reframe_hand_worked_cases() -> None:
    # 0xE9 on the line: 0 1001 0111 1: three falling edges, each a 0x00 with a framing error
    assert reframe(b"\xe9", 9600, 115_200) == bytes(3)
    # at half the rate the receiver samples every second bit: both 0xFF frames make one
    assert reframe(b"\xff\xff", 230_400, 115_200) == b"\xff"
    # a UART tolerates a few percent of mismatch
    data = bytes(range(256))
    assert reframe(data, 115_200, 118_000) == data == reframe(data, 115_200, 112_000)


def test_a_long_low_line_is_one_break_byte() -> None:
    """Each 0x00 at 9600 holds the line low for 96 of 921,600's bits: one 0x00, not ten."""
    assert reframe(bytes(3), 9600, 921_600) == bytes(3)


def test_faults_flip_and_drop_at_their_rates() -> None:
    faults = Faults(FaultConfig(bit_flip_rate=0.01, drop_rate=0.01), seed=1, now=0.0)
    data = bytes(200_000)
    out = faults.corrupt(data)
    assert len(data) - len(out) == faults.bytes_dropped
    assert faults.bytes_dropped == pytest.approx(2000, rel=0.15)
    assert faults.bits_flipped == pytest.approx(2000, rel=0.15)
    assert sum(bin(b).count("1") for b in out) == pytest.approx(faults.bits_flipped, abs=40)


def test_stalls_hold_output_then_release_it() -> None:
    faults = Faults(FaultConfig(stall_every_s=0.5, stall_s=0.1), seed=2, now=0.0)
    held = [faults.stalled(t / 1000) for t in range(5000)]
    runs = np.diff(np.flatnonzero(np.diff(np.array(held, int))))
    assert faults.stalls >= 3
    assert np.all(runs[::2] == 100)


def test_every_reply_length_matches_what_the_unit_sends() -> None:
    host = unit()
    for code in sorted(DATA_CODES):
        host.unit.receive(bytes((code,)), host.t)
        assert len(host.run(0.01)) == REPLIES[code].length


def test_sampling_reply_reflects_settings() -> None:
    host = unit()
    reply = host.send("sampling_settings", function=0, decimation=1, flags=0, **SETTINGS)
    sampling = Sampling()
    assert int.from_bytes(reply[1:3], "big") == sampling.decimation
    assert int.from_bytes(reply[3:5], "big") == sampling.flags


def test_truth_log_keeps_the_newest_records_in_order() -> None:
    log = TruthLog(3)
    for i in range(5):
        log.append((i * 1000, i * 1000 - 7, i * 0.01, i, 0xC2, np.array([1.0, 0, 0, 0])))
    truth = log.arrays()
    assert len(log) == 3
    assert truth["timer"].tolist() == [2, 3, 4]
    assert truth["time_ns"].tolist() == [2000, 3000, 4000]
    assert truth["value_ns"].tolist() == [1993, 2993, 3993]


def test_truth_log_reads_the_same_however_its_rows_are_stored() -> None:
    """Rows go into the columns in batches: any read sees every row so far, in order."""
    log = TruthLog(300)
    for i in range(700):
        log.append((i, i, i * 0.5, i, 0xC2, np.array([i, 0, 0, 1.0])))
        if i % 97 == 0 or i == 699:
            truth = log.arrays()
            assert len(log) == len(truth["time_ns"]) == min(i + 1, 300)
            assert truth["time_ns"].tolist() == list(range(max(0, i - 299), i + 1))
            assert (truth["quaternion"][:, 0] == truth["time_ns"]).all()


@pytest.mark.parametrize(("name", "params"), [("timer", {"function": 0, "value": 0}),
                                              ("firmware_version", {}),
                                              ("write_gyro_bias", {"gyro_bias": [0.0, 0.0, 0.0]})])
@pytest.mark.parametrize("decimation", [1, 4, 10])
def test_replies_while_streaming_leave_at_once_in_timer_order(
        name: str, params: dict[str, Any], decimation: int) -> None:
    """The unit answers at the next calculation cycles, between the records around it."""
    host = unit()
    host.stream(0xC2, decimation)
    host.run(0.3)
    command = encode_command(name, **params)
    reply_code, reply_length = command[0], REPLIES[command[0]].length
    framer = Framer({0xC2, reply_code})
    framer.feed(host.run(0.0023))
    sent = host.t
    host.unit.receive(command, sent)
    batches: list[Batch] = []
    answered = None
    while host.t < sent + 0.2:
        batches += framer.feed(host.run(0.0001, step=0.0001))
        if answered is None and any(b.code == reply_code for b in batches):
            answered = host.t
    assert answered is not None
    line_s = 10 / 115_200
    # the record on the line, then the reply, within a few cycles
    assert answered - sent <= 0.003 + (31 + reply_length) * line_s
    codes = [b.code for b in batches for _ in range(len(b))]
    assert codes.count(reply_code) == 1 and codes.count(0xC2) > 10
    if any(f.name == "timer" for f in REPLIES[reply_code].fields):
        timers = np.concatenate([b["timer"] for b in batches]).astype(np.int64)
        assert np.all(np.diff(timers) >= 0)


def read_timer(host: Host) -> int:
    reply = host.send("timer", 0.01, function=0, value=0)
    assert reply[:1] == b"\xd7" and len(reply) == 7, reply.hex()
    return int.from_bytes(reply[1:5], "big")


def test_sleep_stops_the_timer_and_it_resumes_on_wake() -> None:
    host = unit()
    host.send("timer", function=1, value=1_000_000)
    host.send("mode", 0.0, mode=4)  # 0.01 s after the timer was set
    host.run(2.0)
    host.unit.receive(b"\x00", host.t)
    host.run(0.2)
    ticks = read_timer(host) - 1_000_000
    awake_s = 0.01 + 0.2  # before the sleep command, and since the wake; not the 2 s asleep
    assert ticks == pytest.approx(awake_s * TICKS_PER_SECOND, abs=0.002 * TICKS_PER_SECOND)


def test_commands_sent_behind_a_sleep_are_dropped_and_do_not_wake_it() -> None:
    host = unit()
    host.unit.receive(encode_command("mode", mode=4) + encode_command("firmware_version"),
                      host.t)
    assert host.run(0.5) == bytes((0xD4, 0x04, 0x00, 0xD8))
    assert host.send("firmware_version", 0.05) == b""  # this one only wakes it


def test_power_on_settles_before_it_answers_or_streams() -> None:
    settle = 0.053 + 2 * 15 / 1000
    quiet = SimUnit(UnitConfig(), now=0.0)
    quiet.receive(encode_command("firmware_version"), 0.02)
    assert quiet.poll(settle - 0.001) == b"" and quiet.poll(0.5) == b""
    quiet.receive(encode_command("firmware_version"), settle + 0.001)
    assert quiet.poll(settle + 0.01)[:1] == b"\xe9"
    streaming = SimUnit(UnitConfig(stored=Stored(mode_preset=2, continuous_preset=0xC2)),
                        now=0.0)
    assert streaming.poll(settle - 0.0005) == b""
    assert len(streaming.poll(settle + 0.05)) >= 31


def test_a_partial_command_is_dropped_after_the_inter_byte_timeout() -> None:
    host = unit()
    host.unit.receive(encode_command("mode_preset", mode_preset=3)[:2], host.t)
    host.run(0.15)
    assert host.send("firmware_version", 0.01)[:1] == b"\xe9"
    assert host.unit.stored.mode_preset == 1
    host.unit.receive(encode_command("mode_preset", mode_preset=3)[:2], host.t)
    host.run(0.05)
    host.unit.receive(encode_command("mode_preset", mode_preset=3)[2:], host.t)
    assert host.run(0.01)[:1] == b"\xd5"


def test_a_power_cycle_boots_the_unit_from_its_stored_memory() -> None:
    host = unit()
    host.send("timer", function=1, value=50_000_000)
    host.stream(0xC2, 2)
    host.run(0.2)
    host.unit.power_cycle(host.t)
    cut = host.t
    assert host.run(0.08) == b""
    assert host.send("firmware_version", 0.05) == b""  # still settling
    assert (host.unit.sampling.decimation, host.unit.mode) == (10, 1)
    assert read_timer(host) < (host.t - cut) * TICKS_PER_SECOND + 1


@pytest.mark.parametrize(("width", "mag_width"), [(1, 1), (8, 17), (15, 17), (32, 3)])
def test_the_filter_delay_shows_in_the_data(width: int, mag_width: int) -> None:
    """Values describe the instant (M-1)/2 ms before their cycle, mag (Mm-1)/2 ms."""
    host = unit()
    host.stream(0xCB, 5)
    host.send("sampling_settings", function=1, decimation=5, flags=0, filter_width=width,
              mag_filter_width=mag_width, up_compensation=10, north_compensation=10)
    host.run(0.1)
    recs = one(host.records(0.5, 0xCB), 0xCB)
    truth = host.unit.truth.arrays()
    device = truth["device_s"][np.searchsorted(truth["timer"], recs["timer"])]
    delay, mag_delay = (width - 1) / 2000, (mag_width - 1) / 2000
    motion = host.unit.motion
    shifted = motion.sample(device - delay, 0.005)
    assert np.abs(recs["accel"] - shifted["accel"]).max() < 1e-6
    assert np.abs(recs["ang_rate"] - shifted["ang_rate"]).max() < 1e-6
    assert np.abs(recs["mag"] - motion.magnetometer(device - mag_delay)).max() < 1e-6
    if width > 1:
        assert np.abs(recs["ang_rate"] - motion.sample(device, 0.005)["ang_rate"]).max() > 1e-5
    lag_ns = truth["time_ns"] - truth["value_ns"]
    assert lag_ns[-1] == pytest.approx(delay * 1e9, abs=2)


def test_the_filter_model_can_be_turned_off_and_divides_the_noise() -> None:
    """Each cycle's noise averaged over the factory's 15 cycles: its spread over sqrt(15),
    neighbours sharing 14/15 of it; without the filter model, each cycle's own."""
    motion = MotionConfig(seed=4, static=True, noise_gyro_rad_s=0.01)
    spreads = []
    for on in (True, False):
        host = unit(motion=motion, filter_model=on)
        host.stream(0xC2, 1, 921_600)
        rate = one(host.records(4.0, 0xC2), 0xC2)["ang_rate"].astype(np.float64)
        spreads.append(rate.std())
        shared = np.mean([np.corrcoef(rate[1:, i], rate[:-1, i])[0, 1] for i in range(3)])
        assert shared == pytest.approx(14 / 15 if on else 0.0, abs=0.03)
        truth = host.unit.truth.arrays()
        assert (truth["time_ns"] - truth["value_ns"] == (7_000_000 if on else 0)).all()
    assert spreads[1] == pytest.approx(0.01, rel=0.05)
    assert spreads[0] == pytest.approx(0.01 / np.sqrt(15), rel=0.05)


def test_faults_are_reproducible_from_the_seed_however_the_bytes_are_split() -> None:
    config = FaultConfig(bit_flip_rate=0.01, drop_rate=0.01)
    data = bytes(range(256)) * 200
    whole = Faults(config, seed=7, now=0.0).corrupt(data)
    split = Faults(config, seed=7, now=0.0)
    cuts = [0, 1, 100, 4000, 4001, 30000, len(data)]
    pieces = b"".join(split.corrupt(data[a:b]) for a, b in itertools.pairwise(cuts))
    assert pieces == whole != data
    assert Faults(config, seed=8, now=0.0).corrupt(data) != whole
    stalls = FaultConfig(stall_every_s=0.2, stall_s=0.05, disconnect_every_s=0.5)
    runs = [Faults(stalls, seed=3, now=0.0) for _ in range(2)]
    for faults in runs:
        faults.corrupt(data)
    timeline = [[(f.stalled(t / 1000), f.outage(t / 1000)) for t in range(3000)] for f in runs]
    assert timeline[0] == timeline[1]
