"""The plain values of a run's configuration: its choices, and the defaults that ``--help`` quotes.

They are owned here, not in :mod:`curbside.localize.runconfig` or :mod:`curbside.localize.ronin.stream`
(which take them from here), so that the console commands build their parsers without importing
``dataclasses``: that import alone costs about 10 ms of CPU, against about 75 ms for the whole of
``localize --help``, and every frozen dataclass made at import about 1 ms more. This module imports
nothing.
"""

from __future__ import annotations

from types import SimpleNamespace

#: The methods: GNSS alone; the filter without GNSS (RoNIN+PF); the paper's plain fused filter; curbside's.
MODES = ("gnss", "inertial", "paper", "fused")
VELOCITY_SOURCES = ("auto", "file", "ronin", "pdr")
STEP_SOURCES = ("auto", "file", "detect", "cadence")
FIX_ASSOCIATIONS = ("interpolate", "once")
UNSEEN_VELOCITY_MODES = ("off", "on", "auto")
FAMILIAR_VELOCITY_MODES = ("off", "on", "auto")
FIX_LAG_MODES = ("off", "fixed", "auto")
#: The longest GNSS fix lag a run compensates or estimates (s). A phone receiver's smoothing trails the
#: walker by a few seconds (the estimate, whose candidates run from 1 to 4 s, chose 4 s at most on the
#: IPIN trials); a lag of ``T`` moves each fix forward by about ``T`` times the walking speed, 14 m for
#: 10 s at 1.4 m/s, and a lag much longer than the walk moves it by the whole inertial path so far.
MAX_FIX_LAG_S = 10.0

#: The defaults of :class:`~curbside.localize.runconfig.UnseenVelocityConfig`, field by field (its
#: docstring says what each is and how it was chosen). Read-only.
UNSEEN_VELOCITY_DEFAULTS = SimpleNamespace(
    mode="auto",
    still_speed_mps=0.1,
    still_updates=5,
    settle_s=2.0,
    step_noise_fraction=0.55,
    step_noise_across_fraction=0.25,
    standing_speed_mps=0.6,
    scale_correction_fraction=0.05,
)
#: The defaults of :class:`~curbside.localize.runconfig.FamiliarVelocityConfig`, field by field (its
#: docstring says what each is and how it was chosen). Read-only.
FAMILIAR_VELOCITY_DEFAULTS = SimpleNamespace(
    mode="off",
    window_s=0.5,
    min_speed_mps=0.6,
    jitter_max=0.05,
    min_samples=40,
    final_samples=120,
    heading_noise_deg=0.75,
    step_noise_fraction=0.15,
    scale_init_sigma=0.0,
    scale_correction_fraction=0.0,
)
#: The default of :attr:`curbside.localize.ronin.stream.RoninStreamConfig.stride` (grid samples between
#: RoNIN window starts; its docstring says how it was chosen).
RONIN_STRIDE = 20
