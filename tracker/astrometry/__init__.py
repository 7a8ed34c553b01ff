"""Astrometry for the attitude: time scales, the Earth's velocity, aberration.

* :mod:`~tracker.astrometry.timescale`: TAI (the wire's absolute time),
  UTC with leap seconds (at the edges), TT and Julian dates.
* :mod:`~tracker.astrometry.earth`: the Earth's barycentric velocity from an
  analytic model (about 0.01 km/s).
* :mod:`~tracker.astrometry.aberration`: apparent directions for a moving
  observer (special relativity).
* :mod:`~tracker.astrometry.observer`: one frame's observer context (its
  absolute time, the observer's velocity, where the time came from, and so
  what the solver corrects).
"""
