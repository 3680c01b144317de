"""The map-aware particle filter of Dubiner, Ren & Manduchi, as parts that compose.

=========================  ==================================================================
module                     part
=========================  ==================================================================
:mod:`.config`             every parameter: :class:`FilterConfig` and its sections
:mod:`.correction_config`  the sections of the parts that re-draw particles (recovery, corrections)
:mod:`.particles`          :class:`ParticleSet`, normalisation, the weighted :class:`Estimate`
:mod:`.parts`              :class:`Update`, :class:`GnssFix` and the part interfaces
:mod:`.predict`            :class:`InertialPredictor` (heading drift, jumps, speed scale)
:mod:`.map_likelihood`     :class:`MapLikelihood` (buildings, jaywalking, soft walls)
:mod:`.gnss`               :class:`GnssLikelihood` (robust, tempered, optional bias state)
:mod:`.street_heading`     :class:`StreetHeadingLikelihood`: opt-in heading from the street's axis
:mod:`.resample`           :class:`SystematicResampler`
:mod:`.recovery`           :class:`CollapseRecovery`, :class:`DivergenceRecovery`
:mod:`.pathfit`            the cloud's inertial path beside the recent fixes, and their fit
:mod:`.scale`              :class:`ScaleCorrection`: opt-in GNSS-driven speed-scale re-draws
:mod:`.heading_correction` :class:`HeadingCorrection`: re-draws when good fixes say the velocity turned
:mod:`.segments`           :class:`SegmentEstimator`: which sidewalk segment
:mod:`.calibration`        :class:`SegmentCalibration`: how far to trust it, from the fixes
:mod:`.initiate`           :class:`Initiator`: start at a pose or a fix
:mod:`.smoother`           :class:`FixedLagSmoother`: opt-in positions from the genealogy, later
:mod:`.tracker`            :class:`Tracker`: the streaming filter that runs them
:mod:`.step_input`         the checks of what an app hands :class:`Tracker` (times, steps, fixes)
:mod:`.random`             :class:`~.random.Stream`: seeded normals and uniforms drawn inside kernels
:mod:`.kernelmath`         ``sincos``, ``exp``, ``logaddexp`` that vectorise inside kernels
=========================  ==================================================================

See ``docs/filter.md`` for a drawing of the parts and how to write a new one.
"""

from curbside.localize.filter.calibration import CalibrationConfig, SegmentCalibration
from curbside.localize.filter.config import (
    FilterConfig,
    GnssConfig,
    MapConfig,
    MotionConfig,
    ResampleConfig,
    SmootherConfig,
    StartConfig,
    StreetHeadingConfig,
)
from curbside.localize.filter.correction_config import HeadingCorrectionConfig, RecoveryConfig
from curbside.localize.filter.gnss import GnssLikelihood
from curbside.localize.filter.heading_correction import HeadingCorrection
from curbside.localize.filter.initiate import Initiator
from curbside.localize.filter.map_likelihood import MapLikelihood
from curbside.localize.filter.particles import Estimate, ParticleSet, normalise_and_estimate
from curbside.localize.filter.parts import GnssFix, Likelihood, Predictor, Resampler, Update
from curbside.localize.filter.predict import InertialPredictor
from curbside.localize.filter.recovery import CollapseRecovery, DivergenceRecovery
from curbside.localize.filter.resample import SystematicResampler
from curbside.localize.filter.scale import ScaleCorrection
from curbside.localize.filter.segments import SegmentEstimator, SegmentMode
from curbside.localize.filter.smoother import FixedLagSmoother
from curbside.localize.filter.street_heading import StreetHeadingLikelihood
from curbside.localize.filter.tracker import Tracker

__all__ = [
    "CalibrationConfig",
    "CollapseRecovery",
    "DivergenceRecovery",
    "Estimate",
    "FilterConfig",
    "FixedLagSmoother",
    "GnssConfig",
    "GnssFix",
    "GnssLikelihood",
    "HeadingCorrection",
    "HeadingCorrectionConfig",
    "InertialPredictor",
    "Initiator",
    "Likelihood",
    "MapConfig",
    "MapLikelihood",
    "MotionConfig",
    "ParticleSet",
    "Predictor",
    "RecoveryConfig",
    "ResampleConfig",
    "Resampler",
    "ScaleCorrection",
    "SegmentCalibration",
    "SegmentEstimator",
    "SegmentMode",
    "SmootherConfig",
    "StartConfig",
    "StreetHeadingConfig",
    "StreetHeadingLikelihood",
    "SystematicResampler",
    "Tracker",
    "Update",
    "normalise_and_estimate",
]
