"""What every console command shares: logging set-up and the exit-status contract.

Exit 0 on success; 2 on bad usage or bad input, with one line on stderr naming the file and the
problem; 1 on an internal error; 130 on Ctrl-C; 141 when the reader of stdout goes away (``| head``),
as for a process killed by SIGPIPE. ``CURBSIDE_DEBUG=1`` shows tracebacks.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import logging
import math
import os
import re
import select
import sys
from collections.abc import Callable, Sequence

from curbside.errors import CurbsideInputError
from curbside.localize.runconstants import (
    FAMILIAR_VELOCITY_DEFAULTS,
    FAMILIAR_VELOCITY_MODES,
    UNSEEN_VELOCITY_DEFAULTS,
    UNSEEN_VELOCITY_MODES,
)

#: ``--overwrite`` of the commands that write one file.
OVERWRITE_FILE_HELP = "replace the output file even when curbside did not write it (never one of the inputs)"


#: A number written with a decimal comma (``-122,401``), as in locales whose decimal mark is the comma.
_DECIMAL_COMMA = re.compile(r"[-+]?\d+,\d+")

#: A number as a command line gives it.
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)")

#: The option an argparse error message is about (``argument --bbox: ...``).
_ERROR_OPTION = re.compile(r"argument (-[^ :/]+)")


class _ArgumentParser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line and exit status 2."""

    _arg_strings: Sequence[str] = ()

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        """argparse's, remembering ``args`` for :meth:`error`."""
        self._arg_strings = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> None:  # type: ignore[override]
        message = _decimal_comma_hint(message, self._arg_strings)
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _decimal_comma_hint(message: str, arg_strings: Sequence[str]) -> str:
    """``message`` about an option, or what it would hide: a value of that option written with a decimal
    comma. argparse takes ``-122,401`` for an option (``expected 4 arguments``: it is no negative number
    to argparse) and ``122,401`` for no number; both mean ``-122.401``/``122.401`` in comma locales."""
    option = _ERROR_OPTION.match(message)
    if option is None or option.group(1) not in arg_strings:
        return message
    start = list(arg_strings).index(option.group(1)) + 1
    following = list(itertools.takewhile(lambda a: not a.startswith("--"), arg_strings[start:]))
    for value in following:
        if not ("," in value and all(_NUMBER.fullmatch(part) for part in value.split(","))):
            continue
        if _DECIMAL_COMMA.fullmatch(value):
            return (f"argument {option.group(1)}: {value!r} has a decimal comma: use a decimal point "
                    f"({value.replace(',', '.')})")
        return f"argument {option.group(1)}: {value!r}: separate the numbers with spaces, not commas"
    return message


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None


def positive_int(text: str) -> int:
    """argparse ``type``: an integer >= 1."""
    value = _int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """argparse ``type``: an integer >= 0."""
    value = _int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {value}")
    return value


def seed(text: str) -> int:
    """argparse ``type``: a random seed, an integer >= 0 (numpy refuses negative seeds)."""
    return non_negative_int(text)


def port(text: str) -> int:
    """argparse ``type``: a TCP port, 1 to 65535."""
    value = _int(text)
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number from 1 to 65535, got {value}")
    return value


def finite_float(text: str) -> float:
    """argparse ``type``: a finite number (e.g. a longitude or latitude in degrees)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {value}")
    return value


def positive_float(text: str) -> float:
    """argparse ``type``: a number > 0."""
    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {value}")
    return value


def non_negative_float(text: str) -> float:
    """argparse ``type``: a finite number >= 0 (0 usually turns the option off)."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {value}")
    return value


def unit_interval(text: str) -> float:
    """argparse ``type``: a number in [0, 1] (a weight or a probability)."""
    value = finite_float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must lie in [0, 1], got {value}")
    return value


def set_overrides(pairs: list[str]) -> dict[str, str]:
    """``--set KEY=VALUE`` arguments as ``{KEY: VALUE}`` (values still text; see
    :func:`curbside.configio.with_overrides`).

    Raises
    ------
    CurbsideInputError
        A pair without ``=`` or without a key.
    """
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise CurbsideInputError("--set", f"expected KEY=VALUE, got {pair!r}")
        out[key.strip()] = value.strip()
    return out


def _fix_lag(value: str) -> dict[str, object]:
    """``--fix-lag``: ``auto``, ``off`` or a lag in seconds (``fixed``)."""
    if value in ("auto", "off"):
        return {"fix_lag.mode": value}
    try:
        seconds = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, off or seconds, got {value!r}") from None
    if not math.isfinite(seconds) or seconds < 0:
        raise argparse.ArgumentTypeError(f"the lag must be a non-negative number of seconds, got {value!r}")
    return {"fix_lag.mode": "fixed", "fix_lag.lag_s": seconds}


def add_config_options(parser: argparse.ArgumentParser, set_help: str) -> None:
    """``--unseen-velocity``, ``--familiar-velocity``, ``--fix-lag`` and ``--set KEY=VALUE``: the
    run-configuration options (read back with :func:`config_overrides`)."""
    u, f = UNSEEN_VELOCITY_DEFAULTS, FAMILIAR_VELOCITY_DEFAULTS
    parser.add_argument(
        "--unseen-velocity",
        nargs="?",
        const="on",
        choices=UNSEEN_VELOCITY_MODES,
        help="the motion model for a velocity model that has not seen this phone, its carrier or the place "
        f"(step noise {u.step_noise_fraction:g} along the step and {u.step_noise_across_fraction:g} across "
        f"it, standing below {u.standing_speed_mps:g} m/s, speed-scale "
        f"correction {u.scale_correction_fraction:g}): 'on' (the flag alone) from the start, 'auto' once "
        f"the model reads {u.still_speed_mps:g} m/s or more while no footstep comes, 'off' never "
        f"(default: {u.mode} for --mode fused, off for the baselines; tune with --set "
        "unseen_velocity.KEY=VALUE)",
    )
    parser.add_argument(
        "--familiar-velocity",
        nargs="?",
        const="auto",
        choices=FAMILIAR_VELOCITY_MODES,
        help="the calm motion model for a velocity model fitted to this walker (heading noise "
        f"{f.heading_noise_deg:g} deg, step noise {f.step_noise_fraction:g}, no speed-scale state): 'auto' "
        "(the flag alone) while the velocity's speed changes by less than "
        f"{100 * f.jitter_max:g} %% from one {f.window_s:g} s window to the next (a second filter runs "
        f"beside the default one until {f.final_samples} such samples decide it), 'on' from the start, "
        f"'off' never (default: {f.mode}; a smooth speed that is 10 %% or more off loses to good fixes; "
        "tune with --set familiar_velocity.KEY=VALUE)",
    )
    parser.add_argument(
        "--fix-lag",
        type=_fix_lag,
        metavar="auto|off|SECONDS",
        help="move each GNSS fix forward by the inertial motion a receiver lag holds back (phones' fixes "
        "trail the walker): SECONDS for a known lag, 'auto' to estimate it from the whole recording "
        "before a batch run (a stream, which cannot look ahead, takes fix_lag.lag_s), 'off' (default; "
        "tune with --set fix_lag.KEY=VALUE)",
    )
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help=set_help)


def config_overrides(args: argparse.Namespace) -> dict[str, object]:
    """The overrides :func:`add_config_options` asked for: the ``--unseen-velocity`` and
    ``--familiar-velocity`` modes, ``--fix-lag``, then ``--set``."""
    modes = {f"{key}.mode": value for key, value in (("unseen_velocity", args.unseen_velocity),
                                                       ("familiar_velocity", args.familiar_velocity))
             if value is not None}
    return {**modes, **(args.fix_lag or {}), **set_overrides(args.set)}


def make_parser(prog: str, description: str) -> argparse.ArgumentParser:
    """A parser with ``-v/--verbose`` and one-line usage errors."""
    parser = _ArgumentParser(prog=prog, description=description)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    return parser


def interrupted(prog: str) -> int:
    """Say ``PROG: interrupted`` on stderr and return 130, the status of Ctrl-C (no traceback)."""
    sys.stderr.write(f"{prog}: interrupted\n")
    return 130


def run_cli(
    prog: str,
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
) -> int:
    """Parse ``argv``, call ``args.func(args)`` and map exceptions onto exit statuses.

    Parameters
    ----------
    prog
        Program name used as the message prefix.
    parser
        Parser whose sub-commands set ``func`` with ``set_defaults``.
    argv
        Arguments (``None``: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status.
    """
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    # Libraries that set their own logger levels (dask's distributed logs at INFO) still stop here.
    for handler in logging.getLogger().handlers:
        handler.setLevel(level)
    func: Callable[[argparse.Namespace], int | None] | None = getattr(args, "func", None)
    if func is None:
        parser.print_help(sys.stderr)
        return 2
    debug = os.environ.get("CURBSIDE_DEBUG") == "1"
    try:
        status = int(func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler, not at interpreter exit
        return status
    except BrokenPipeError as exc:
        if _stdout_reader_gone():
            # the reader went away (``| head``): stop quietly, as a process killed by SIGPIPE would
            with contextlib.suppress(OSError, ValueError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 141
        if debug:
            raise
        return _internal_error(prog, exc)  # another pipe or socket broke: a worker, a subprocess
    except CurbsideInputError as exc:
        if debug:
            raise
        sys.stderr.write(f"{prog}: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        return interrupted(prog)
    except Exception as exc:  # noqa: BLE001 - the contract: internal errors exit 1, one line
        if debug:
            raise
        return _internal_error(prog, exc)


def _internal_error(prog: str, exc: Exception) -> int:
    """Say what went wrong inside on one line of stderr and return 1."""
    sys.stderr.write(
        f"{prog}: internal error: {type(exc).__name__}: {exc} (CURBSIDE_DEBUG=1 for a traceback)\n"
    )
    return 1


def _stdout_reader_gone() -> bool:
    """Whether stdout is a pipe whose reader has closed it (poll reports an error on it); ``True`` where
    that cannot be told (no ``poll``, no file descriptor), as it was before this check."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return True
