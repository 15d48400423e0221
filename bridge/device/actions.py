"""Operator actions on a unit: one function each, run on a port or inside a bridge.

The same table serves ``gx3 info|configure|capture-bias|set-timer|stationary-test|
reset`` on a port and the command queryable of a running bridge, so both behave
alike. An action that writes non-volatile memory (or resets the unit) needs
``confirm``: the CLI asks the operator before it sets it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bridge.device.session import Session, UnitInfo
from bridge.exceptions import DeviceError
from bridge.protocol.table import STATIONARY_TEST_BITS

Params = dict[str, Any]


@dataclass(frozen=True)
class Action:
    """One operator action: its name, a line of help, and how to run it.

    ``run`` returns a JSON-able result; ``persists`` tells whether ``params`` ask for a
    lasting change; ``effect`` what it does to a running stream: "none",
    "reconfigure" (settings changed), "discontinuity" (the timer jumps) or "restart"
    (the unit comes back as after power-up).
    """

    name: str
    summary: str
    run: Callable[[Session, UnitInfo, Params], Params]
    persists: Callable[[Params], bool] = lambda p: bool(p.get("persist"))
    effect: str = "none"


def _info(session: Session, info: UnitInfo, params: Params) -> Params:
    """What the unit says it is and how it starts.

    ``record`` is what its bridge streams (0 on a port, where nothing streams).
    """
    fresh = session.identify()
    mode_preset = int(session.command("mode_preset", mode_preset=0)["mode_preset"])
    return {"firmware": fresh.firmware, "firmware_text": fresh.firmware_text, **fresh.ids,
            "sampling": fresh.sampling, "baud": fresh.baud, "mode_preset": mode_preset,
            "continuous_preset": fresh.continuous_preset, "record": info.record}


_SAMPLING = ("decimation", "flags", "filter_width", "mag_filter_width", "up_compensation",
             "north_compensation")


def _configure(session: Session, info: UnitInfo, params: Params) -> Params:
    persist = bool(params.get("persist"))
    done: Params = {}
    changes = {k: params[k] for k in _SAMPLING if params.get(k) is not None}
    if changes:
        session.apply_sampling(info, persist, **changes)
        done["sampling"] = info.sampling
    if params.get("mode_preset") is not None:
        reply = session.command("mode_preset", persist=True, mode_preset=params["mode_preset"])
        done["mode_preset"] = reply["mode_preset"]
    if params.get("continuous_preset") is not None:
        reply = session.command("continuous_preset", persist=True,
                                continuous_preset=params["continuous_preset"])
        done["continuous_preset"] = reply["continuous_preset"]
    if params.get("baud") is not None:
        session.change_baud(info, int(params["baud"]), persist)
        done["baud"] = info.baud
    if not done:
        raise DeviceError("nothing to configure: give a setting to change")
    if info.notes:
        done["notes"] = list(info.notes)
    warning = info.line_warning() if session.paced else None
    if warning:
        done["warning"] = warning
    return done


def _configure_persists(params: Params) -> bool:
    return bool(params.get("persist")) or params.get("mode_preset") is not None \
        or params.get("continuous_preset") is not None


def _capture_bias(session: Session, info: UnitInfo, params: Params) -> Params:
    ms = int(params.get("sampling_ms", 10_000))
    reply = session.command("capture_gyro_bias", sampling_time_ms=ms,
                            timeout=ms / 1000 + 2.0, retries=0)
    result: Params = {"gyro_bias": reply["gyro_bias"], "sampling_ms": ms}
    if params.get("persist"):
        session.command("transfer_to_nonvolatile", persist=True, quantity=2)
        result["stored"] = True
    return result


def _set_timer(session: Session, info: UnitInfo, params: Params) -> Params:
    value = int(params.get("value", 0))
    return {"timer": session.command("timer", function=1, value=value)["timer"]}


def _stationary_test(session: Session, info: UnitInfo, params: Params) -> Params:
    word = int(session.command("stationary_test")["test_result"])
    return {"test_result": word,
            "flags": {name: bool(word >> bit & 1) for bit, name in STATIONARY_TEST_BITS.items()}}


def _reset(session: Session, info: UnitInfo, params: Params) -> Params:
    session.send("device_reset", persist=True)
    return {"reset": True}


ACTIONS: dict[str, Action] = {a.name: a for a in (
    Action("info", "Read firmware, ID strings and settings", _info, lambda p: False),
    Action("configure", "Change sampling, baud rate or presets", _configure, _configure_persists,
           "reconfigure"),
    Action("capture_bias", "Capture the gyro bias of a still unit (0xCD)", _capture_bias),
    Action("set_timer", "Restart the timer at a value (0xD7)", _set_timer, lambda p: False,
           "discontinuity"),
    Action("stationary_test", "Run the self-test (0xDA)", _stationary_test, lambda p: False),
    Action("reset", "Soft-reset the unit (0xFE)", _reset, lambda p: True, "restart"),
)}


def run_action(name: str, session: Session, info: UnitInfo, params: Params,
               confirmed: bool) -> Params:
    """Run one action on a unit.

    Args:
        name: The action (``ACTIONS``).
        session: The session with the unit.
        info: What bring-up learned of the unit; an action that changes a setting
            updates it.
        params: The action's parameters (JSON-able).
        confirmed: The operator agreed to a lasting change; without it, an action that
            would make one is refused.

    Returns:
        The action's result, JSON-able.

    Raises:
        DeviceError: An unknown action, a lasting change not confirmed, or a unit that
            did not do what was asked.
    """
    action = ACTIONS.get(name)
    if action is None:
        raise DeviceError(f"unknown action {name!r}; known: {', '.join(ACTIONS)}")
    if action.persists(params) and not confirmed:
        raise DeviceError(f"{name} would make a lasting change to the unit; confirm it")
    return action.run(session, info, params)
