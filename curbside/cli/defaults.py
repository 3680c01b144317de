"""The choices and defaults that the parsers show, copied from the modules that own them.

Building the parsers must stay cheap (``localize --help`` in well under a second, a Ctrl-C at start-up
answered at once), and the modules that own these values import numpy, scipy, numba or torch: the
run configuration, the readers, the evaluation runner, the RoNIN stream. Each value here is a copy of
its owner's, named beside it; ``tests/test_cli_startup.py`` checks every one against the owner.
"""

from __future__ import annotations

from types import SimpleNamespace

#: :data:`curbside.localize.runconfig.MODES`
MODES = ("gnss", "inertial", "paper", "fused")
#: :data:`curbside.localize.runconfig.VELOCITY_SOURCES`
VELOCITY_SOURCES = ("auto", "file", "ronin", "pdr")
#: :data:`curbside.localize.runconfig.UNSEEN_VELOCITY_MODES`
UNSEEN_VELOCITY_MODES = ("off", "on", "auto")
#: :data:`curbside.localize.runconfig.FAMILIAR_VELOCITY_MODES`
FAMILIAR_VELOCITY_MODES = ("off", "on", "auto")
#: The defaults of :class:`curbside.localize.runconfig.UnseenVelocityConfig` that ``--help`` quotes.
UNSEEN_VELOCITY = SimpleNamespace(
    mode="auto",
    still_speed_mps=0.1,
    step_noise_fraction=0.55,
    step_noise_across_fraction=0.25,
    standing_speed_mps=0.6,
    scale_correction_fraction=0.05,
)
#: The defaults of :class:`curbside.localize.runconfig.FamiliarVelocityConfig` that ``--help`` quotes.
FAMILIAR_VELOCITY = SimpleNamespace(
    mode="off",
    window_s=0.5,
    jitter_max=0.05,
    final_samples=120,
    heading_noise_deg=0.75,
    step_noise_fraction=0.15,
)
#: :data:`curbside.evaluate.runner.METHODS`
METHODS = ("gnss", "inertial", "paper", "fused")
#: The keys of :data:`curbside.localize.readers._platform.PLATFORM_OPTIONS`
PLATFORM_OPTIONS = ("android", "ios", "ios-standardised")
#: :data:`curbside.osmseg.build.READ_MARGIN_M`
READ_MARGIN_M = 60.0
#: ``RoninStreamConfig().stride`` (:mod:`curbside.localize.ronin.stream`)
RONIN_STRIDE = 20
#: :data:`curbside.io.OVERWRITE_FILE_HELP`
OVERWRITE_FILE_HELP = "replace the output file even when curbside did not write it (never one of the inputs)"
