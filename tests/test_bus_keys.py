"""Keys: one spelling for every key, unit names that Zenoh can carry, clear errors otherwise."""

from __future__ import annotations

import pytest
import zenoh

from bridge.bus.keys import UnitKeys, check_unit, fleet, unit_of
from bridge.exceptions import BadName


def test_unit_keys_follow_the_design() -> None:
    keys = UnitKeys("imu0")
    assert (keys.imu, keys.status, keys.event, keys.info, keys.command, keys.raw, keys.alive) == (
        "gx3/imu0/imu", "gx3/imu0/status", "gx3/imu0/event", "gx3/imu0/info",
        "gx3/imu0/command", "gx3/imu0/raw", "gx3/imu0/alive")
    assert UnitKeys("left-wing.2", prefix="lab/gx3").imu == "lab/gx3/left-wing.2/imu"
    assert fleet("imu") == "gx3/*/imu"
    assert zenoh.KeyExpr(fleet("imu")).intersects(zenoh.KeyExpr(keys.imu))
    assert unit_of("gx3/imu0/imu") == "imu0"
    assert unit_of("lab/gx3/u/status", prefix="lab/gx3") == "u"


@pytest.mark.parametrize("bad", ["", "a/b", "*", "imu$", "a?b", "x#", "two words", "@admin",
                                 "é", "x" * 65])
def test_unsafe_unit_names_are_refused_with_what_is_allowed(bad: str) -> None:
    with pytest.raises(BadName, match="cannot be used in a Zenoh key: use 1-64 letters"):
        check_unit(bad)
    with pytest.raises(BadName):
        UnitKeys(bad)


def test_every_accepted_name_makes_valid_zenoh_keys() -> None:
    for name in ("imu0", "A_b-c.d", "0", "x" * 64):
        for key in (UnitKeys(name).imu, UnitKeys(name).alive):
            assert str(zenoh.KeyExpr(key)) == key


def test_bad_prefix_and_foreign_keys_are_clear_errors() -> None:
    with pytest.raises(BadName, match="key prefix 'gx3/' cannot be used"):
        UnitKeys("imu0", prefix="gx3/")
    with pytest.raises(BadName, match="not of the form gx3/<unit>/<leaf>"):
        unit_of("other/imu0/imu")
    with pytest.raises(BadName, match="unknown key leaf 'imus'"):
        fleet("imus")
