"""What an archive tells of its units: noise (Allan deviation) and magnetometer iron."""

from bridge.analysis.allan import AllanSums, NoiseFit, averaging_factors, read_off
from bridge.analysis.magcal import IronCalibration, UnitIron, fit, read_document
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
    "NoiseFit",
    "SensorNoise",
    "UnitIron",
    "UnitNoise",
    "UnitSamples",
    "averaging_factors",
    "collect_samples",
    "fit",
    "kalibr_yaml",
    "read_document",
    "read_off",
    "stretch_text",
    "unit_noise",
    "units_noise",
]
