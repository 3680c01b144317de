"""What :class:`~curbside.localize.filter.Tracker` accepts: the checks on its arguments.

An app calls the tracker directly, with no session file or live batch checked before it
(:mod:`curbside.localize.live_input` checks those), so the tracker checks its own input and refuses,
naming the argument and its value, what would otherwise be tracked into nonsense without a word:

- times that are not seconds on a clock (``|t|`` under
  :data:`~curbside.localize.live_input.MAX_ABS_T_S`: not epoch milliseconds or nanoseconds), or that do
  not increase from one update to the next;
- a ``dt`` that is not positive or disagrees with the update times (:data:`DT_TOLERANCE_S`,
  :data:`DT_TOLERANCE_FRACTION`);
- a motion that is not an (east, north) pair of finite numbers, or faster than a walker
  (:data:`MAX_SPEED_MPS`, :data:`STEP_SLACK_M`);
- a fix that is not a :class:`~curbside.localize.filter.parts.GnssFix` of numbers.

Every refusal is a :class:`~curbside.errors.CurbsideValueError`: both ``except CurbsideInputError``
and ``except ValueError`` (what the tracker raised before it named the argument) catch it. None of the
checks fires on what the engine sends: on the 216 runs of the benchmark's 108 tune walks (``paper6`` and
``open``, with and without the start pose; 136,000 updates) its updates came 0.003-1.0 s apart and
moved at most 2.8 m/s (1.6 m in one update).
"""

from __future__ import annotations

import math
import numbers

from curbside.errors import CurbsideInputError, CurbsideValueError
from curbside.localize.filter.parts import GnssFix
from curbside.localize.live_input import MAX_ABS_T_S, check_time_value

#: Fastest a walker may move between two updates by the inertial input, m/s: sprinters peak near
#: 10 m/s, a brisk walk is 2 m/s. A velocity in mm/s or cm/s, or a displacement in cm, is refused.
MAX_SPEED_MPS = 10.0
#: ... plus this much, m: one footstep reported with next to no time since the previous update (a step
#: detected twice) is not a sprint.
STEP_SLACK_M = 2.0
#: ``dt`` may differ from ``t`` minus the previous update's ``t`` by this much, s, plus
#: :data:`DT_TOLERANCE_FRACTION` of it: two sensor clocks read a sample or two apart (0.02 s at 50 Hz)
#: agree, while a ``dt`` in milliseconds is 1000 times off.
DT_TOLERANCE_S = 0.1
DT_TOLERANCE_FRACTION = 0.1


def valid_fix(fix: GnssFix | None) -> bool:
    """Whether ``fix`` is a fix at all: finite position, accuracy positive and finite."""
    return (
        fix is not None
        and math.isfinite(fix.x)
        and math.isfinite(fix.y)
        and math.isfinite(fix.accuracy_m)
        and fix.accuracy_m > 0
    )


def real(value: object, name: str) -> float:
    """``value`` as a float (NaN and infinities pass); a non-number is refused, naming ``name``.

    Raises
    ------
    CurbsideValueError
        ``value`` is not a real number (a string, ``None``, a bool, a sequence).
    """
    if isinstance(value, float):  # float and numpy.float64: the common case, checked fast
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return float(value)
    raise CurbsideValueError(name, f"{value!r} is not a number")


def finite(value: object, name: str) -> float:
    """``value`` as a finite float.

    Raises
    ------
    CurbsideValueError
        Naming ``name`` and the value: not a number, or not finite.
    """
    number = real(value, name)
    if not math.isfinite(number):
        raise CurbsideValueError(name, f"{value!r} is not a finite number")
    return number


def pair(value: object, name: str) -> tuple[float, float]:
    """An ``(east, north)`` pair of finite floats.

    Raises
    ------
    CurbsideValueError
        Naming ``name`` (or ``name[0]``, ``name[1]``) and the value.
    """
    try:
        east, north = value
    except (TypeError, ValueError):
        raise CurbsideValueError(name, f"{value!r} is not an (east, north) pair") from None
    if isinstance(east, float) and isinstance(north, float) and math.isfinite(east + north):
        return east, north  # the common case, once per footstep
    return finite(east, f"{name}[0]"), finite(north, f"{name}[1]")


def time_s(t: object, name: str = "t") -> float:
    """A time in seconds on a clock (:func:`~curbside.localize.live_input.check_time_value`).

    Raises
    ------
    CurbsideValueError
        Naming ``name``: not a finite number, or ``|t|`` too large for seconds.
    """
    if isinstance(t, float) and abs(t) < MAX_ABS_T_S:  # the common case (NaN fails the comparison)
        return t
    t = finite(t, name)
    try:
        check_time_value(t, name)
    except CurbsideInputError as exc:
        raise CurbsideValueError(exc.source, exc.problem) from None
    return t


def check_fix(fix: object, name: str) -> None:
    """Refuse anything but a :class:`GnssFix` of numbers (an invalid fix's NaN accuracy passes).

    Raises
    ------
    CurbsideValueError
        Naming ``name`` (or the field) and the value.
    """
    if not isinstance(fix, GnssFix):
        raise CurbsideValueError(
            name, f"{fix!r} is not a GnssFix (make one with Tracker.fix(lat=..., lon=..., accuracy_m=...))"
        )
    x, y, accuracy_m = fix
    if not (isinstance(x, float) and isinstance(y, float) and isinstance(accuracy_m, float)):
        for field, value in zip(GnssFix._fields, fix, strict=True):
            real(value, f"{name}.{field}")


def step_displacement(
    velocity_en: object, dt: object, displacement_en: object, dt_s: float
) -> tuple[float, float]:
    """The displacement (m east, north) of one :meth:`~curbside.localize.filter.Tracker.step`, checked.

    Parameters
    ----------
    velocity_en, dt, displacement_en
        The step's arguments: a velocity (m/s) and its duration (s), or a displacement (m).
    dt_s
        Time since the previous update, s (NaN before the start: no comparison with it).

    Raises
    ------
    CurbsideValueError
        Naming the argument and its value: no motion given, not an (east, north) pair of finite
        numbers, ``dt`` not positive or disagreeing with ``dt_s``, or faster than :data:`MAX_SPEED_MPS`.
    """
    if dt is not None:
        dt = finite(dt, "dt")
        if dt <= 0:
            raise CurbsideValueError("dt", f"{dt!r} is not a positive duration in seconds")
        if abs(dt - dt_s) > DT_TOLERANCE_S + DT_TOLERANCE_FRACTION * dt_s:  # False for a NaN dt_s
            raise CurbsideValueError(
                "dt", f"{dt!r} s disagrees with t minus the previous update's t, {dt_s:.4g} s (milliseconds?)"
            )
    if displacement_en is not None:
        name, (dx, dy) = "displacement_en", pair(displacement_en, "displacement_en")
    elif velocity_en is not None and dt is not None:
        name, (vx, vy) = "velocity_en", pair(velocity_en, "velocity_en")
        dx, dy = vx * dt, vy * dt
    else:
        raise CurbsideValueError("step()", "needs velocity_en and dt, or displacement_en")
    moved_m = math.hypot(dx, dy)
    if moved_m > MAX_SPEED_MPS * dt_s + STEP_SLACK_M:  # False for a NaN dt_s
        raise CurbsideValueError(
            name,
            f"moves the walker {moved_m:.4g} m in {dt_s:.4g} s, faster than {MAX_SPEED_MPS:g} m/s "
            "(a velocity in mm/s, a displacement in cm?)",
        )
    return dx, dy
