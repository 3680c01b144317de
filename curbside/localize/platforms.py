"""The ``--platform`` values of a Sensor Logger export, here rather than in the reader
(:mod:`curbside.localize.readers._platform`, which imports numpy and scipy) so that the console
commands offer them without importing it. This module imports nothing.
"""

from __future__ import annotations

#: ``--platform`` values (:func:`~curbside.localize.readers._platform.device_from_option`) and the
#: reading each names.
PLATFORM_OPTIONS = {"android": "android", "ios": "ios", "ios-standardised": "standardised ios"}
