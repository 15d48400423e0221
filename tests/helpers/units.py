"""Emulated units that several test modules run: their serials, motion, records and rates."""

from __future__ import annotations

from dataclasses import replace

from bridge.protocol.table import Flag
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import unit_configs
from bridge.sim.state import Sampling, Stored
from bridge.sim.unit import UnitConfig

#: 0xC2 at 1 kHz on a 921,600 baud line, coning and sculling on: a bridge's hardest rate
FAST = UnitConfig(
    serial="FAST0001", motion=MotionConfig(seed=11),
    stored=Stored(mode_preset=2, continuous_preset=0xC2, baud=921_600,
                  sampling=Sampling(decimation=1, flags=int(Flag.CONING_SCULLING))))
#: 0xC8 at 100 Hz on the default line
SLOW = replace(FAST, serial="SLOW0001",
               stored=Stored(mode_preset=2, continuous_preset=0xC8))

#: a unit at rest streaming 0xC2 at 100 Hz: what the pipeline's tests start from
STATIC_UNIT = UnitConfig(serial="PIPE0001", motion=MotionConfig(seed=5, static=True),
                         stored=Stored(mode_preset=2, continuous_preset=0xC2))

#: two moving units streaming 0xCC at 100 Hz, their clocks 80 and -60 ppm off: what the
#: recorder's tests record
TWO_UNITS = unit_configs(2, UnitConfig(serial="REC", motion=MotionConfig(seed=21),
                                       stored=Stored(mode_preset=2, continuous_preset=0xCC)),
                         clock_ppm=[80.0, -60.0])

#: 0xCC at 500 Hz on a 921,600 baud line, its clock 40 ppm off
FIVE_HUNDRED_HZ = UnitConfig(
    serial="STALL001", motion=MotionConfig(seed=7), clock_ppm=40.0,
    stored=Stored(mode_preset=2, continuous_preset=0xCC, baud=921_600,
                  sampling=Sampling(decimation=2)))
FIVE_HUNDRED_HZ_PERIOD = 125  # ticks from one of its records to the next
