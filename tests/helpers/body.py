"""Units fixed to one body turned by hand, captured in virtual time and replayed into an
archive, beside what their mountings and time shifts truly are."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bridge.archive.reader import ArchiveReader
from bridge.archive.walk import read_samples_archive
from bridge.export.tables import offline_times, sample_table
from bridge.ingest.replay import replay
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import MotionConfig, Mounting, handheld
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import HostDelivery, UsbDelivery

BODY_SEED = 5
#: A GX3's white noise (Kalibr's units) and a few mg and mrad/s of bias.
ACCEL_DENSITY, GYRO_DENSITY = 0.0008, 0.0002


@dataclass(frozen=True)
class BodyUnit:
    """One unit on the body: its mounting, clock, link and filter."""

    name: str
    turned: tuple[float, float, float] = (0.0, 0.0, 0.0)  # roll, pitch, yaw, degrees
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, body axes
    ppm: float = 0.0
    delivery: HostDelivery = field(default_factory=UsbDelivery)
    baud: int | None = None  # None: the unit's own USB port
    filter_width: int = 15
    link_latency_s: float = 0.0
    code: int = 0xC2

    @property
    def mounting(self) -> Mounting:
        return Mounting.turned(self.turned, self.lever_arm, BODY_SEED)


@dataclass
class Body:
    """An archive of units on one body, and the emulator's truth of each."""

    path: Path
    units: list[BodyUnit]
    truth: dict[str, dict[str, np.ndarray]]

    def read(self) -> tuple[ArchiveReader, dict[str, np.ndarray]]:
        """The archive, and its samples as gx3 export times them."""
        data = read_samples_archive(self.path)
        return data, sample_table(data, None, None, None, None, offline_times(data))

    def unit(self, name: str) -> BodyUnit:
        return next(u for u in self.units if u.name == name)

    def rotation(self, ref: str, unit: str) -> np.ndarray:
        """The true rotation from ``ref``'s axes to ``unit``'s."""
        return self.unit(unit).mounting.matrix @ self.unit(ref).mounting.matrix.T

    def lever_arm(self, ref: str, unit: str) -> np.ndarray:
        """The true lever arm from ``ref`` to ``unit``, in ``ref``'s axes."""
        a, b = self.unit(ref), self.unit(unit)
        return np.asarray(a.mounting.matrix @ (np.array(b.lever_arm) - np.array(a.lever_arm)))

    def errors(self, table: dict[str, np.ndarray], unit: str) -> tuple[np.ndarray, np.ndarray]:
        """Each of a unit's exported samples' true instant, and its time_ns less it (ns)."""
        rows = np.flatnonzero(table["unit"] == unit)
        truth = self.truth[unit]
        at = np.searchsorted(truth["timer"], table["timer"][rows])
        assert (truth["timer"][at] == table["timer"][rows]).all()
        value = truth["value_ns"][at]
        return value, table["time_ns"][rows] - value

    def needed_shift(self, table: dict[str, np.ndarray], ref: str, unit: str) -> float:
        """The time shift (s) the archive really needs to put ``unit`` on ``ref``'s time.

        Each unit's exported time_ns is off its true instant by an error that may vary
        slowly (where the reads say little of its clock); t_ref = t_unit + shift for one
        physical instant needs shift = e_ref - e_unit, at each instant. A constant shift
        can give its mean only, weighted as the rates' agreement weighs instants: by how
        fast the rates change then (the square of the reference's rate's slope).
        """
        ref_value, ref_error = self.errors(table, ref)
        value, error = self.errors(table, unit)
        rows = table["unit"] == ref
        rate = np.column_stack([table[f"ang_rate_{a}"][rows] for a in "xyz"]).astype(float)
        weight = np.sum(np.gradient(rate, ref_value / 1e9, axis=0) ** 2, axis=1)
        difference = ref_error - np.interp(ref_value, value, error)
        return float(np.sum(weight * difference) / np.sum(weight)) / 1e9


def body_archive(folder: Path, units: list[BodyUnit], seconds: float,
                 decimation: int = 2) -> Body:
    """``units`` fixed to one body turned by hand for ``seconds``, each captured on its
    own link and clock, with noise and biases, and replayed into ``folder/body.mcap``."""
    captures, truth = [], {}
    for i, u in enumerate(units):
        motion = handheld(MotionConfig(
            seed=20 + i, accelerometer_noise_density=ACCEL_DENSITY,
            gyroscope_noise_density=GYRO_DENSITY, gyro_bias_rad_s=(0.002 * i, -0.001, 0.001),
            accel_bias_g=(0.002, -0.001 * i, 0.001)), u.mounting)
        config = UnitConfig(clock_ppm=u.ppm, clock_wander_ppm=0.5, clock_seed=i,
                            motion=motion, link_latency_s=u.link_latency_s)
        stream = streaming_config(config, code=u.code, decimation=decimation,
                                  filter_width=u.filter_width,
                                  **({} if u.baud is None else {"baud": u.baud}))
        capture = synthesize(stream, u.delivery, seconds)
        captures.append(capture.write(folder / f"{u.name}.raw.mcap", u.name))
        truth[u.name] = capture.truth
    replay(captures, folder / "body.mcap")
    return Body(folder / "body.mcap", units, truth)
