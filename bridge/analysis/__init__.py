"""What an archive tells of its units: noise, magnetometer iron, and mounts on one body."""

from bridge.analysis.align import UnitMotion, align, fit_mount, unit_motion
from bridge.analysis.allan import AllanSums, NoiseFit, averaging_factors, read_off
from bridge.analysis.magcal import IronCalibration, UnitIron, fit, read_document
from bridge.analysis.mounts import Mount, MountFit, Mounts, mounts_yaml, read_mounts
from bridge.analysis.noise import (
    NOISE_KEYS,
    SensorNoise,
    UnitNoise,
    UnitSamples,
    collect_samples,
    kalibr_yaml,
    stretch_text,
    unit_noise,
    units_noise,
)

__all__ = [
    "NOISE_KEYS",
    "AllanSums",
    "IronCalibration",
    "Mount",
    "MountFit",
    "Mounts",
    "NoiseFit",
    "SensorNoise",
    "UnitIron",
    "UnitMotion",
    "UnitNoise",
    "UnitSamples",
    "align",
    "averaging_factors",
    "collect_samples",
    "fit",
    "fit_mount",
    "kalibr_yaml",
    "mounts_yaml",
    "read_document",
    "read_mounts",
    "read_off",
    "stretch_text",
    "unit_motion",
    "unit_noise",
    "units_noise",
]
