"""Time scales, the Earth's velocity model and aberration against published values."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tracker.astrometry.aberration import aberrate, observer_beta
from tracker.astrometry.earth import AU_KM, C_KM_S, earth_barycentric_velocity_km_s
from tracker.astrometry.timescale import (
    TAI_NS_MAX,
    TAI_NS_MIN,
    TimeError,
    check_tai_ns,
    jd_tt_from_tai_ns,
    julian_year_from_tai_ns,
    tai_ns_from_utc_iso,
    utc_iso_from_tai_ns,
)

_ARCSEC = math.degrees(1.0) * 3600.0

# IAU SOFA's own test of epv00 (t_sofa_c.c, t_epv00): the Earth's barycentric
# velocity in AU/day at TDB JD 2400000.5 + 53411.52501161.
_SOFA_JD = 2400000.5 + 53411.52501161
_SOFA_V_AU_DAY = (-0.1091874268116823295e-1, -0.1246525461732861538e-1,
                  -0.5404773180966231279e-2)
# More dates, from SOFA's epv00 (through pyerfa 2.0), km/s, ICRS: (TT, JD TT, v).
_EPV00 = (
    ("1991-04-02T00:00:00", 2448348.5, (5.644289, -26.833105, -11.634697)),
    ("2000-01-01T12:00:00", 2451545.0, (-29.784947, -5.029754, -2.180644)),
    ("2010-07-15T06:00:00", 2455392.75, (27.035205, 10.367282, 4.495153)),
    ("2024-03-20T03:06:00", 2460389.629166667, (-0.638175, -27.438364, -11.893961)),
    ("2026-11-23T00:00:00", 2461367.5, (-26.347440, 13.423598, 5.818460)),
    ("2045-09-01T18:00:00", 2468225.25, (10.157212, 25.407461, 11.012280)),
)
# The model's stated accuracy (tracker.astrometry.earth); the issue asks for 0.05 km/s.
_V_TOL_KM_S = 0.01


def test_earth_velocity_matches_sofa_test_vector():
    ref = np.array(_SOFA_V_AU_DAY) * AU_KM / 86400.0
    assert np.linalg.norm(earth_barycentric_velocity_km_s(_SOFA_JD) - ref) < _V_TOL_KM_S


@pytest.mark.parametrize(("label", "jd_tt", "v_ref"), _EPV00, ids=[d[0] for d in _EPV00])
def test_earth_velocity_matches_epv00(label, jd_tt, v_ref):
    err = np.linalg.norm(earth_barycentric_velocity_km_s(jd_tt) - np.array(v_ref))
    assert err < _V_TOL_KM_S, f"{label}: {err * 1000:.1f} m/s"


def test_mean_orbital_speed_gives_the_constant_of_aberration():
    """kappa = 20.49552 arcsec (IAU 1976) is the mean orbital speed over c."""
    jd = 2451545.0 + np.linspace(0.0, 365.25, 400, endpoint=False)
    speeds = [np.linalg.norm(earth_barycentric_velocity_km_s(t)) for t in jd]
    kappa = np.mean(speeds) / C_KM_S * _ARCSEC
    assert kappa == pytest.approx(20.4955, abs=0.02)


def test_aberration_at_right_angles_to_the_velocity_is_arcsin_beta():
    beta = np.array([0.0, 30.0 / C_KM_S, 0.0])
    u = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    a = aberrate(u, beta)
    shift = np.arctan2(np.linalg.norm(np.cross(a, u), axis=1), np.sum(a * u, axis=1))
    np.testing.assert_allclose(shift, math.asin(30.0 / C_KM_S), rtol=1e-9)


def test_aberration_moves_stars_toward_the_apex_and_keeps_the_apex():
    beta = np.array([0.6, -0.3, 0.2]) * (37.5 / C_KM_S) / np.linalg.norm([0.6, -0.3, 0.2])
    apex = beta / np.linalg.norm(beta)
    np.testing.assert_allclose(aberrate(apex, beta), apex, atol=1e-15)
    rng = np.random.default_rng(3)
    u = rng.normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    a = aberrate(u, beta)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-15)
    assert np.all(a @ apex >= u @ apex - 1e-15)
    # first order: |beta| sin(theta); second order is below beta^2 = 1.6e-8 rad
    theta = np.arccos(np.clip(u @ apex, -1, 1))
    shift = np.arccos(np.clip(np.sum(a * u, axis=1), -1, 1))
    np.testing.assert_allclose(shift, np.linalg.norm(beta) * np.sin(theta), atol=2e-8)


def test_aberration_inverse_is_minus_beta_and_in_place_works():
    beta = np.array([1e-4, -2e-5, 3e-5])
    rng = np.random.default_rng(4)
    u = rng.normal(size=(50, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    a = aberrate(u, beta)
    np.testing.assert_allclose(aberrate(a, -beta), u, atol=1e-15)
    buf = u.copy()
    assert aberrate(buf, beta, out=buf) is buf
    np.testing.assert_allclose(buf, a, atol=1e-16)


def test_aberration_refuses_speeds_at_or_above_light():
    with pytest.raises(ValueError, match="not below light"):
        aberrate(np.array([1.0, 0, 0]), np.array([0.0, 1.0, 0.0]))


def test_observer_beta_adds_the_geocentric_velocity():
    t = tai_ns_from_utc_iso("2026-03-20T12:00:00Z")
    earth = observer_beta(t)
    leo = observer_beta(t, (0.0, 7.5, 0.0))
    np.testing.assert_allclose((leo - earth) * C_KM_S, [0.0, 7.5, 0.0], atol=1e-9)
    assert 29.2 < np.linalg.norm(earth) * C_KM_S < 30.4


@pytest.mark.parametrize(("utc", "tai_minus_utc"), [
    ("1972-01-01T00:00:00Z", 10), ("1999-01-01T00:00:00Z", 32),
    ("2016-12-31T23:59:59Z", 36), ("2017-01-01T00:00:00Z", 37), ("2026-11-23T17:29:15Z", 37)])
def test_utc_to_tai_uses_the_leap_second_table(utc, tai_minus_utc):
    import calendar
    import time
    posix = calendar.timegm(time.strptime(utc, "%Y-%m-%dT%H:%M:%SZ"))
    assert tai_ns_from_utc_iso(utc) == (posix + tai_minus_utc) * 1_000_000_000


def test_a_leap_second_is_its_own_tai_second_and_prints_as_60():
    before = tai_ns_from_utc_iso("2016-12-31T23:59:59Z")
    leap = tai_ns_from_utc_iso("2016-12-31T23:59:60.25Z")
    after = tai_ns_from_utc_iso("2017-01-01T00:00:00Z")
    assert leap - before == 1_250_000_000 and after - before == 2_000_000_000
    assert utc_iso_from_tai_ns(leap) == "2016-12-31T23:59:60.250000000Z"
    with pytest.raises(TimeError, match="no leap second"):
        tai_ns_from_utc_iso("2017-06-30T23:59:60Z")


@given(st.integers(min_value=TAI_NS_MIN, max_value=TAI_NS_MAX))
def test_tai_utc_round_trip(t):
    assert tai_ns_from_utc_iso(utc_iso_from_tai_ns(t)) == t


@pytest.mark.parametrize("bad", ["2026-11-23T17:29:15", "2026-13-01T00:00:00Z",
                                 "2026-02-30T00:00:00Z", "1969-12-31T23:59:59Z", "yesterday", 5])
def test_bad_utc_strings_are_one_line_errors(bad):
    with pytest.raises(TimeError) as err:
        tai_ns_from_utc_iso(bad)
    assert "\n" not in str(err.value)


def test_j2000_is_2000_0_in_tt():
    t = tai_ns_from_utc_iso("2000-01-01T11:58:55.816Z")     # J2000.0 = 12:00 TT
    assert jd_tt_from_tai_ns(t) == (2451544.5, 0.5)
    assert julian_year_from_tai_ns(t) == 2000.0


@pytest.mark.parametrize("bad", [-1, 0, TAI_NS_MIN - 1, TAI_NS_MAX + 1, 2**64 - 1, 1.5e18])
def test_absolute_times_outside_1972_2200_are_refused(bad):
    with pytest.raises(TimeError, match="outside 1972-2200"):
        check_tai_ns(bad)
