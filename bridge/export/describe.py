"""What an exported table says about itself, so that it needs nothing else to be understood.

Its column names, each column's physical unit and frame, and the file's provenance
(units' Info, source archive, options, schema version): a Parquet file read years
later, or by someone who never saw this project, explains itself.

Column names are lower-case identifiers that no DuckDB keyword and no pandas DataFrame
attribute takes, so they work unquoted in SQL and with pandas attribute access. A CSV
file, which has no metadata, carries each column's unit in its header instead
(``csv_header``).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from google.protobuf.json_format import MessageToDict

from bridge.bus import gx3_pb2
from bridge.bus.codec import HEADER, elements
from bridge.bus.gx3_pb2 import ImuSample, Info

#: The layout of an export's columns and metadata; changes when either changes meaning.
SCHEMA_VERSION = "gx3.v1"
#: Quantity fields of ImuSample in schema order (the column order of an export).
QUANTITY_ORDER = tuple(f.name for f in ImuSample.DESCRIPTOR.fields if f.name not in HEADER
                       and f.name != "unit")
_SUFFIX = {"euler": ("roll", "pitch", "yaw")}
#: Between an aligned column's unit label and its flat name: ``imu_1__accel_x``.
ALIGNED_SEPARATOR = "__"

BODY = "body FRD (the sensor's x forward, y right, z down, as marked on the case)"
CONVENTIONS = (
    "Body frame FRD (sensor x forward, y right, z down); earth frame NED (north, east, "
    "down). M (m11..m33, row-major) maps earth to body: v_body = M v_earth; body-to-earth "
    "is its transpose. The quaternion q0..q3 is scalar first (q0 = w) and is the rotation "
    "of M (earth to body); Rerun and ROS want x y z w. roll, pitch, yaw are ZYX Euler "
    "angles of the body against NED. time_ns is ns since the Unix epoch (UTC) on the host "
    "clock: the best estimate of the instant a sample describes, each unit's clock "
    "re-estimated over the whole recording and its filter delay taken out; time_utc is the "
    "same instant as a timestamp. A null value is one the record does not carry (or, "
    "aligned, an instant outside the unit's samples or inside a gap).")

# column -> (physical unit, description); quantities' units come from gx3.proto
_HEAD: dict[str, tuple[str, str]] = {
    "unit": ("", "unit name, as in the key gx3/<unit>/imu"),
    "command": ("unitless", "record command byte (0xC1..0xDF), as in the 3DM-GX3 manual"),
    "timer": ("tick (1/62500 s)", "device timer as on the wire: uint32, 62,500 ticks per "
                                  "second, wraps after about 19 h"),
    "ticks": ("tick (1/62500 s)", "timer unwrapped to 64 bits; starts again near 0 only "
                                  "after a device reset or timer set"),
    "time_ns": ("ns", "the row's instant, ns since the Unix epoch (UTC) on the host clock; "
                      "of a sample, the best estimate of the instant its values describe: "
                      "each unit's clock re-estimated over the whole recording (live times "
                      "where the unit's Info is not archived), filter delay taken out"),
    "time_utc": ("ns", "time_ns as a UTC timestamp"),
    "time_uncertainty_ns": ("ns", "the most time_ns can be off by, as the reads bound it "
                                  "(time_ns is the middle of the instants they allow); 0: "
                                  "not known (a UART's reads bound records from one side)"),
    "live_time_ns": ("ns", "time_ns as the bridge published it live (from the past only)"),
    "rx_ns": ("ns", "host receive time (ns since the Unix epoch) of the read that completed "
                    "the record; includes transport latency"),
    "kind": ("", "what happened: GAP, RESET, ROLLOVER, RECONNECT, ..."),
    "amount": ("unitless", "how many: records dropped for a GAP, bytes skipped for a "
                           "RESYNC, messages for LOST, REJECTED and SHED, else 1"),
    "detail": ("", "the event in words"),
}
# Columns an export derives from the quantities: (physical unit, frame, description).
_DERIVED: dict[str, tuple[str, str, str]] = {
    "mag_heading": ("rad", "body x axis against earth NED, from magnetic north toward east",
                    "tilt-compensated heading from accel and the iron-corrected mag "
                    "(gx3.mag_cal): the unit's own yaw as a compass would find it"),
}
_QUANTITY: dict[str, tuple[str, str]] = {
    "raw_accel": (BODY, "raw accelerometer A/D codes (0..131071)"),
    "raw_ang_rate": (BODY, "raw gyro A/D codes"),
    "accel": (BODY, "specific force"),
    "stab_accel": (BODY, "gyro-stabilised gravity estimate"),
    "ang_rate": (BODY, "angular rate"),
    "delta_ang": (BODY, "integral of ang_rate over the sample period"),
    "delta_vel": (BODY, "integral of accel over the sample period"),
    "mag": (BODY, "magnetic field"),
    "stab_mag": (BODY, "gyro-stabilised magnetic field estimate"),
    "m": ("earth NED to body FRD: v_body = M v_earth; body to earth is the transpose",
          "orientation matrix M, row-major (m<row><column>)"),
    "c": (BODY, "orientation update matrix over one calculation cycle, row-major"),
    "euler": ("body FRD against earth NED, ZYX (yaw, then pitch, then roll)",
              "roll, pitch, yaw"),
    "quaternion": ("earth NED to body FRD (the rotation of M); scalar first: q0 = w, "
                   "q1 q2 q3 = x y z", "attitude quaternion"),
    "temperature": ("", "12-bit temperature A/D codes: 0 magnetometer, 1 gyro Y / accel X, "
                        "2 gyro X / accel Z and Y, 3 gyro Z"),
}


def flat_names(quantity: str, elements: int) -> list[str]:
    """Flat column names of a quantity: accel_x.., m11..m33, roll pitch yaw, q0..q3."""
    if quantity in _SUFFIX:
        return list(_SUFFIX[quantity])
    if quantity == "quaternion":
        return [f"q{i}" for i in range(elements)]
    if elements == 9:
        return [f"{quantity}{r}{c}" for r in range(1, 4) for c in range(1, 4)]
    if elements == 3:
        return [f"{quantity}_{axis}" for axis in "xyz"]
    return [f"{quantity}_{i}" for i in range(elements)]


def _physical_unit(quantity: str) -> str:
    """The unit gx3.proto declares for a quantity ("unitless" where it declares none)."""
    options = ImuSample.DESCRIPTOR.fields_by_name[quantity].GetOptions()
    # the generated stub types extensions as plain FieldDescriptors
    return str(options.Extensions[cast(Any, gx3_pb2.physical_unit)]) or "unitless"


def unit_labels(units: Iterable[str]) -> dict[str, str]:
    """Each unit's column prefix in aligned output.

    Lower-case, letters, digits and ``_``, starting with a letter; distinct (``_2``,
    ``_3``.. where two names would meet).
    """
    labels: dict[str, str] = {}
    for unit in sorted(set(units)):
        base = re.sub(r"[^a-z0-9_]", "_", unit.lower())
        if not base[:1].isalpha():
            base = f"unit_{base}"
        label, k = base, 2
        while label in labels.values():
            label, k = f"{base}_{k}", k + 1
        labels[unit] = label
    return labels


# flat column name -> (quantity, element index)
_FLAT = {name: (q, i) for q in QUANTITY_ORDER for i, name in enumerate(flat_names(q, elements(q)))}


def column_metadata(name: str, labels: Mapping[str, str]) -> dict[str, str]:
    """Field metadata of one column: physical unit, frame, description.

    For an aligned column, also the unit it belongs to.
    """
    about: dict[str, str] = {}
    for unit, label in labels.items():
        prefix = label + ALIGNED_SEPARATOR
        if name.startswith(prefix) and (name[len(prefix):] in _FLAT
                                        or name[len(prefix):] in _DERIVED):
            about["gx3_unit"] = unit
            name = name[len(prefix):]
            break
    if name in _HEAD:
        physical, description = _HEAD[name]
        frame = ""
    elif name in _DERIVED:
        physical, frame, description = _DERIVED[name]
    elif name in _FLAT:
        quantity, index = _FLAT[name]
        physical = _physical_unit(quantity)
        frame, description = _QUANTITY[quantity]
        if quantity == "temperature":
            description = f"{description} (this is {index})"
    else:
        return about
    about |= {"physical_unit": physical, "frame": frame, "description": description}
    return {k: v for k, v in about.items() if v}


def csv_header(name: str, labels: Mapping[str, str]) -> str:
    """A CSV column's header: its name, and its physical unit in brackets, ``accel_x [g]``.

    A CSV file has no metadata to hold the units, so they go where a spreadsheet shows
    them and where every reader (pandas, polars, DuckDB, pyarrow) takes them with no
    option: the one header line. A column with no unit keeps its bare name (``unit``,
    ``m11``, ``q0``), as does one whose name ends in its unit already (``time_ns``) and
    ``time_utc``, whose values carry their zone and which readers then parse as
    timestamps by themselves.

    Args:
        name: The column's name (as in Parquet).
        labels: Each unit's column prefix in aligned output (``unit_labels``).

    Returns:
        The header.
    """
    unit = column_metadata(name, labels).get("physical_unit", "unitless")
    if unit == "unitless" or name == "time_utc" or name.endswith(f"_{unit}"):
        return name
    return f"{name} [{unit}]"


@dataclass(frozen=True)
class About:
    """The file-level facts of an export: which archive, which units, which options."""

    source: Path
    infos: Mapping[str, Info | None]
    options: Mapping[str, object] = field(default_factory=dict)
    mag_cal: Mapping[str, object] = field(default_factory=dict)  # unit -> calibration file
    noise: Mapping[str, object] = field(default_factory=dict)  # the noise file, covariances
    mounts: Mapping[str, object] = field(default_factory=dict)  # the mounts file applied

    def metadata(self) -> dict[str, str]:
        """Parquet file metadata.

        Returns:
            Key-value pairs, values JSON where structured: schema version, product,
            conventions, source archive, export options, the units' Info,
            calibrations, the noise file with the covariances it gives, and the mounts
            file applied.
        """
        labels = unit_labels(self.infos)
        units = {u: {"column_prefix": labels[u],
                     "info": None if info is None else MessageToDict(
                         info, preserving_proto_field_name=True)}
                 for u, info in sorted(self.infos.items())}
        extra = {"gx3.mag_cal": json.dumps(dict(self.mag_cal))} if self.mag_cal else {}
        if self.noise:
            extra["gx3.noise"] = json.dumps(dict(self.noise))
        if self.mounts:
            extra["gx3.mounts"] = json.dumps(dict(self.mounts))
        return {
            "gx3.schema": SCHEMA_VERSION,
            "gx3.product": f"gx3-bridge {importlib.metadata.version('gx3-bridge')}",
            "gx3.conventions": CONVENTIONS,
            "gx3.source": json.dumps({"name": self.source.name,
                                      "bytes": self.source.stat().st_size,
                                      "sha256": _file_sha256(self.source)}),
            "gx3.export": json.dumps(dict(self.options)),
            "gx3.units": json.dumps(units),
        } | extra


def _file_sha256(path: Path) -> str:
    """The hex SHA-256 of a file, as ``sha256sum`` prints it."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()
