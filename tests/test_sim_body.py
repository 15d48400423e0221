"""Units fixed to one body in the emulator: each sees the body's motion as a rigid body
makes it felt where the unit sits and as its mounting turns it, whatever its clock; a
link's constant extra latency delays every byte by exactly that; and `gx3 sim --body` and
`gx3 demo --body` build such units from their options."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bridge.fleet.demo import BODY_MOUNTS, BODY_SEED, fleet
from bridge.protocol.convert import STANDARD_GRAVITY, euler_to_m, quaternion_to_m
from bridge.protocol.framer import Framer
from bridge.sim.capture import WALL_NS, streaming_config, synthesize
from bridge.sim.motion import Motion, MotionConfig, Mounting, handheld
from bridge.sim.options import SimOptions
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UartDelivery, UsbDelivery

T = np.linspace(2.0, 40.0, 1501)
MOUNTED = Mounting.turned((180.0, 0.0, 90.0), (0.3, -0.2, 0.5), body_seed=4)


@pytest.fixture(scope="module")
def body() -> Motion:
    return Motion(handheld(MotionConfig(seed=1), Mounting(body_seed=4)))


def test_a_unit_at_the_bodys_origin_unturned_is_the_body(body: Motion) -> None:
    """The mounting takes the body's trajectory from its own seed, not the unit's."""
    unit = Motion(handheld(MotionConfig(seed=9), Mounting(body_seed=4)))
    for name, values in unit.sample(T, 0.01).items():
        if name != "temperature":
            np.testing.assert_array_equal(values, body.sample(T, 0.01)[name], err_msg=name)


def test_a_mounted_unit_feels_the_rigid_bodys_motion_where_it_sits(body: Motion) -> None:
    """Its specific force is the body origin's plus the second derivative of where it
    is (M^T r, by finite differences here), turned into its axes; its rate, attitude,
    field and update matrix are the body's turned."""
    unit = Motion(handheld(MotionConfig(seed=9), MOUNTED))
    mine, theirs = unit.sample(T, 0.01), body.sample(T, 0.01)
    r, arm, h = MOUNTED.matrix, np.array(MOUNTED.lever_arm_m), 1e-3

    def where(t: np.ndarray) -> np.ndarray:  # the unit's place, earth axes, from the origin
        return np.asarray(np.einsum("nji,j->ni", euler_to_m(body.euler_and_rates(t)[0]), arm))

    accel = (where(T + h) - 2 * where(T) + where(T - h)) / h ** 2
    lever = np.einsum("nij,nj->ni", theirs["m"], accel) / STANDARD_GRAVITY
    np.testing.assert_allclose(mine["accel"], (theirs["accel"] + lever) @ r.T, atol=1e-5)
    assert np.abs(lever).max() > 0.2  # in g: the lever arm is felt
    np.testing.assert_allclose(mine["ang_rate"], theirs["ang_rate"] @ r.T, atol=1e-12)
    np.testing.assert_allclose(mine["m"], r @ theirs["m"], atol=1e-12)
    np.testing.assert_allclose(quaternion_to_m(mine["quaternion"]), r @ theirs["m"], atol=1e-12)
    np.testing.assert_allclose(mine["mag"], theirs["mag"] @ r.T, atol=1e-12)
    np.testing.assert_allclose(mine["c"], r @ theirs["c"] @ r.T, atol=1e-12)
    start, middle = (unit.sample(T - d, 0.01, only=("accel",))["accel"] for d in (0.01, 0.005))
    simpson = (start + 4 * middle + mine["accel"]) / 6  # the force's mean over each period
    np.testing.assert_allclose(mine["delta_vel"] / 0.01, simpson, atol=1e-6)


def test_the_hand_turns_briskly_within_a_gx3s_ranges(body: Motion) -> None:
    t = np.arange(0.0, 180.0, 0.01)
    sample = body.sample(t, 0.01, only=("accel", "ang_rate"))
    rate, force = sample["ang_rate"], sample["accel"]
    assert np.all(np.std(rate, axis=0) > 0.2)  # every axis turns
    assert np.abs(rate).max() < np.radians(300) and np.abs(force).max() < 5.0
    alpha = np.gradient(rate, t, axis=0)
    assert np.sqrt(np.mean(np.sum(alpha ** 2, axis=1))) > 1.0  # rad/s²: a lever arm shows


def test_units_on_their_own_clocks_feel_one_body_at_each_true_instant() -> None:
    """Two units 180 ppm apart, each timed by its truth (value_ns): what each sent is the
    body's motion at that instant, host seconds since their common power-up."""
    origin = Motion(handheld(MotionConfig(seed=0), Mounting(body_seed=4)))
    for ppm, seed in ((90.0, 1), (-90.0, 2)):
        motion = handheld(MotionConfig(seed=seed), Mounting(body_seed=4))
        capture = synthesize(streaming_config(UnitConfig(clock_ppm=ppm, motion=motion),
                                              decimation=10), UsbDelivery(seed=seed), 20.0)
        truth = capture.truth
        timers, _ = capture.records()
        at = np.searchsorted(truth["timer"], timers)
        rates = origin.sample((truth["value_ns"][at] - WALL_NS) / 1e9, 0.01,
                              only=("ang_rate",))["ang_rate"]
        framer = Framer(expect=[0xC2])
        sent = np.concatenate([b["ang_rate"] for d in capture.data for b in framer.feed(d)])
        np.testing.assert_allclose(sent, rates, atol=2e-6)  # float32 on the wire


def test_a_links_extra_latency_delays_every_byte_by_exactly_that() -> None:
    config = streaming_config(UnitConfig(motion=MotionConfig(seed=3)), decimation=10,
                              baud=115200)
    uart = UartDelivery(os_latency_mean_s=0.0, stall_every_s=0.0)
    plain = synthesize(config, uart, 5.0)
    late = synthesize(replace(config, link_latency_s=0.0032), uart, 5.0)
    assert plain.data == late.data
    np.testing.assert_array_equal(late.rx_ns - plain.rx_ns, 3_200_000)
    for name in ("time_ns", "value_ns", "timer"):
        np.testing.assert_array_equal(late.truth[name], plain.truth[name])


def test_sim_body_options_mount_each_unit_on_one_body() -> None:
    setup = SimOptions(tcp="127.0.0.1:0", units=3, seed=6, body=True,
                       mount=("180,0,90", "2,-1.5,177"), lever_arm=("0.3,0,0",),
                       link_latency=(0.0, 3.2)).setup()
    mountings = [cfg.motion.mounting for cfg in setup.configs]
    assert all(m is not None and m.body_seed == 6 for m in mountings)
    assert [cfg.motion.seed for cfg in setup.configs] == [6, 7, 8]  # noise: their own
    assert mountings[0] == Mounting.turned((180.0, 0.0, 90.0), (0.3, 0.0, 0.0), 6)
    assert mountings[1] == Mounting.turned((2.0, -1.5, 177.0), (0.0, 0.0, 0.0), 6)
    assert mountings[2] == Mounting(6)
    assert [cfg.link_latency_s for cfg in setup.configs] == [0.0, 0.0032, 0.0]
    assert all(cfg.motion.band_hz == (0.15, 0.8) for cfg in setup.configs)


def test_demo_body_mounts_its_fleet_as_its_table_says() -> None:
    units = fleet(4, 0xCC, 100.0, 20.0, body=True)
    for unit, (turned, arm, latency) in zip(units, BODY_MOUNTS, strict=True):
        assert unit.config.motion.mounting == Mounting.turned(turned, arm, BODY_SEED)
        assert unit.config.link_latency_s == latency
    assert units[3].notes[:2] == ["turned (0, 90, 0)°, (0, -0.3, -0.2) m from imu1",
                                  "link +3.2 ms"]
    assert all(u.config.motion.mounting is None for u in fleet(2, 0xCC, 100.0, 20.0))
