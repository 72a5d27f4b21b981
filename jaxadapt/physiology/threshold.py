"""Increment thresholds: TVI curves, trolands, and thresholds implied by a response.

Pure functions on arrays of any shape that follow the dtype of their inputs
(lists and tuples are taken as arrays); a negative luminance or illuminance
gives NaN.
Retinal illuminance in trolands (td), luminance in cd/m2.

References
----------
Reinhard, Ward, Pattanaik, Debevec (2005), *High Dynamic Range Imaging*,
chapter 6: §6.2 (Weber's law), §6.2.2 (the rod
and cone TVI curves of Rushton and MacLeod, trolands), §6.2.4 (the
response-threshold relation), §6.3.2 (Ward's use of a TVI model).
"""

import jax.numpy as jnp

from jaxadapt.physiology import pupil
from jaxadapt.physiology._inputs import array_like, nonnegative
from jaxadapt.physiology.response import N_HUNT, naka_rushton, power

__all__ = [
    "tvi_rod",
    "tvi_cone",
    "tvi_rod_cone",
    "trolands",
    "tvi_luminance",
    "tvi_blackwell",
    "TVI_MODELS",
    "increment_threshold",
    "increment_sensitivity",
    "relative_threshold",
    "relative_threshold_small_delta",
]


@array_like
def tvi_rod(I_b):
    """Rod increment threshold of Rushton and MacLeod: ``dI = 0.1 (I_b + 0.015)`` (Fig 6.7).

    Parameters
    ----------
    I_b : array_like
        Background retinal illuminance, td.

    Returns
    -------
    array
        Threshold increment, td: 0.0015 td in the dark, a Weber fraction of
        10 % on bright backgrounds; NaN where ``I_b < 0``.

    Examples
    --------
    >>> round(float(tvi_rod(0.0)), 6)
    0.0015
    """
    return nonnegative(I_b, 0.1 * (I_b + 0.015))


@array_like
def tvi_cone(I_b):
    """Cone increment threshold of Rushton and MacLeod: ``dI = 0.02 (I_b + 8)`` (Fig 6.7).

    Parameters
    ----------
    I_b : array_like
        Background retinal illuminance, td.

    Returns
    -------
    array
        Threshold increment, td: 0.16 td in the dark, a Weber fraction of
        2 % on bright backgrounds; NaN where ``I_b < 0``.

    Examples
    --------
    >>> round(float(tvi_cone(0.0)), 6)
    0.16
    """
    return nonnegative(I_b, 0.02 * (I_b + 8.0))


@array_like
def tvi_rod_cone(I_b):
    """Threshold of the more sensitive of the rod and cone systems (the lower envelope).

    An increment is seen when either system detects it, so the threshold is
    ``min(tvi_rod, tvi_cone)``: rods below the crossing of Fig 6.7 at
    ``0.1585 / 0.08 = 1.98`` td, cones above.

    Parameters
    ----------
    I_b : array_like
        Background retinal illuminance, td.

    Returns
    -------
    array
        Threshold increment, td.
    """
    return jnp.minimum(tvi_rod(I_b), tvi_cone(I_b))


@array_like
def trolands(L, d):
    """Retinal illuminance ``T = L * pi d^2 / 4`` of luminance ``L`` seen through a pupil ``d``.

    One troland is 1 cd/m2 seen through a pupil of 1 mm2 (§6.2.2).

    Parameters
    ----------
    L : array_like
        Luminance, cd/m2.
    d : array_like
        Pupil diameter, mm (for the natural pupil, e.g.
        :func:`jaxadapt.physiology.pupil.diameter_moon_spencer` of ``L``).

    Returns
    -------
    array
        Retinal illuminance, td; NaN where ``L < 0`` or ``d < 0``.

    Examples
    --------
    >>> round(float(trolands(100.0, 2.0)), 4)
    314.1593
    """
    return nonnegative(L, L * pupil.area(d))


@array_like
def tvi_luminance(L_b, diameter=pupil.diameter_moon_spencer):
    """Rushton and MacLeod's threshold converted to luminance through the natural pupil.

    ``dL = tvi_rod_cone(T_b) / A(d(L_b))`` with ``T_b = L_b A(d(L_b))``: the
    background and the increment reach the retina through the same pupil,
    whose diameter is set by the background.

    Parameters
    ----------
    L_b : array_like
        Background luminance, cd/m2.
    diameter : callable
        Pupil diameter (mm) as a function of luminance (cd/m2); Moon and
        Spencer's by default.

    Returns
    -------
    array
        Threshold increment, cd/m2.

    Notes
    -----
    The chapter gives both curves in trolands; we use the same photopic
    trolands for the rods, as the chapter does (a scotopic conversion would
    need the spectrum of each pixel).

    Examples
    --------
    >>> round(float(tvi_luminance(1e4) / 1e4), 4)  # cone Weber fraction
    0.02
    """
    A = pupil.area(diameter(L_b))
    return tvi_rod_cone(L_b * A) / A


@array_like
def tvi_blackwell(L_b):
    """Blackwell's threshold as used by Ward (1994): ``dL = 0.0594 (1.219 + L_b^0.4)^2.5``.

    Parameters
    ----------
    L_b : array_like
        Background (adaptation) luminance, cd/m2.

    Returns
    -------
    array
        Threshold increment, cd/m2.

    References
    ----------
    Ward (1994), *A contrast-based scalefactor for luminance display*,
    Graphics Gems IV, pp. 415-421: the TVI model of Ward's JND mapping
    (chapter 6, §6.3.2, Eq 6.3).

    Examples
    --------
    >>> round(float(tvi_blackwell(0.0)), 4)
    0.0975
    """
    return 0.0594 * (1.219 + power(L_b, 0.4)) ** 2.5


#: TVI models by name: background luminance (cd/m2) to threshold (cd/m2).
TVI_MODELS = {"rushton-macleod": tvi_luminance, "blackwell": tvi_blackwell}


@array_like
def increment_threshold(I_b, sigma_b, delta, R_max=1.0, n=N_HUNT):
    """Threshold increment implied by a Naka-Rushton response and a criterion ``delta`` (§6.2.4).

    The increment that raises the response of a receptor adapted to ``I_b``
    (semi-saturation ``sigma_b``, Eq 6.2) by ``delta`` above its plateau
    response ``R_b = R_max I_b^n / (I_b^n + sigma_b^n)``, to first order in
    ``delta`` as the chapter derives it::

        dI = delta sigma_b (1/n) R_max (R_b + delta)^((1-n)/n)
             / (R_max - R_b - delta)^((n+1)/n),

    which is ``delta dI/dR`` at ``R = R_b + delta`` (the derivative of the
    inverse of Eq 6.2). With ``I_b = 0`` (``R_b = 0``) and ``sigma_b =
    sigma_dark`` it is the dark-adapted threshold ``dI_dark``.

    Parameters
    ----------
    I_b : array_like
        Background intensity (any unit, that of ``sigma_b``), ``>= 0``.
    sigma_b : array_like
        Semi-saturation constant at that background, ``> 0``.
    delta : array_like
        Criterion response, in ``(0, R_max - R_b)``.
    R_max : array_like
        Maximum response.
    n : array_like
        Exponent of Eq 6.2.

    Returns
    -------
    array
        Threshold increment, in the unit of ``I_b``.

    Examples
    --------
    >>> round(float(increment_threshold(0.0, 1.0, 0.01, n=1.0)), 6)  # 0.01 / 0.99^2
    0.010203
    """
    R, headroom = _criterion_response(I_b, sigma_b, delta, R_max, n)
    return delta * sigma_b / n * R_max * power(R, (1.0 - n) / n) / power(headroom, (n + 1.0) / n)


def _criterion_response(I_b, sigma_b, delta, R_max, n):
    """The response ``R = R_b + delta`` a threshold increment must reach, and
    its headroom ``R_max - R`` below saturation, 0 where ``R`` is beyond it
    (no increment raises the response by ``delta``)."""
    R = naka_rushton(I_b, sigma_b, R_max, n) + delta
    return R, jnp.maximum(R_max - R, 0.0)


@array_like
def increment_sensitivity(I_b, sigma_b, delta, R_max=1.0, n=N_HUNT):
    """``1 / dI`` of :func:`increment_threshold`, in 1/(unit of ``I_b``).

    Written as the reciprocal so that a saturated receptor
    (``R_b + delta >= R_max``: no increment raises the response by ``delta``) has
    sensitivity 0 with a finite gradient instead of an infinite threshold,
    which is what a fit through saturation needs.
    """
    R, headroom = _criterion_response(I_b, sigma_b, delta, R_max, n)
    return n * power(headroom, (n + 1.0) / n) / (delta * sigma_b * R_max * power(R, (1.0 - n) / n))


@array_like
def relative_threshold(I_b, sigma_b, sigma_dark, delta, R_max=1.0, n=N_HUNT):
    """Threshold relative to the dark-adapted one, ``dI / dI_dark`` (§6.2.4, first line).

    ``(sigma_b / sigma_dark) ((R_b + delta) / delta)^((1-n)/n)
    ((R_max - delta) / (R_max - R_b - delta))^((n+1)/n)``: the ratio of
    :func:`increment_threshold` at ``(I_b, sigma_b)`` and at
    ``(0, sigma_dark)``.

    For ``n = 1`` and a receptor adapted so that ``sigma_b = I_b`` it is
    ``(I_b / sigma_dark) ((R_max - delta) / (R_max / 2 - delta))^2``,
    proportional to ``I_b``: Weber's law.

    Parameters
    ----------
    I_b : array_like
        Background intensity, ``>= 0``.
    sigma_b : array_like
        Semi-saturation constant at that background.
    sigma_dark : array_like
        Semi-saturation constant of the dark-adapted receptor.
    delta : array_like
        Criterion response.
    R_max : array_like
        Maximum response.
    n : array_like
        Exponent of Eq 6.2.

    Returns
    -------
    array
        ``dI / dI_dark``, dimensionless.

    Examples
    --------
    >>> round(float(relative_threshold(0.0, 2.0, 2.0, 0.01)), 6)
    1.0
    """
    dark = increment_threshold(jnp.zeros_like(I_b), sigma_dark, delta, R_max, n)
    return increment_threshold(I_b, sigma_b, delta, R_max, n) / dark


@array_like
def relative_threshold_small_delta(I_b, sigma_b, sigma_dark, delta, R_max=1.0, n=N_HUNT):
    """Closed form of ``dI / dI_dark`` for ``delta << R_b`` (§6.2.4, last line).

    ``(1 / sigma_dark) (delta / R_max)^((n-1)/n) (I_b^n + sigma_b^n)^2
    / (I_b^(n-1) sigma_b^n)``. For ``n = 1`` and ``sigma_b = I_b`` it is
    ``4 I_b / sigma_dark``: Weber's law, as the chapter states.

    Parameters
    ----------
    I_b : array_like
        Background intensity, ``> 0``.
    sigma_b : array_like
        Semi-saturation constant at that background.
    sigma_dark : array_like
        Semi-saturation constant of the dark-adapted receptor.
    delta : array_like
        Criterion response, small against ``R_b``.
    R_max : array_like
        Maximum response.
    n : array_like
        Exponent of Eq 6.2.

    Returns
    -------
    array
        ``dI / dI_dark``, dimensionless. The approximation drops ``delta``
        against ``R_b``, so it fails on dim backgrounds (``R_b -> 0``),
        where :func:`relative_threshold` tends to ``sigma_b / sigma_dark``.

    Examples
    --------
    >>> float(relative_threshold_small_delta(5.0, 5.0, 1.0, 0.01, n=1.0))
    20.0
    """
    In, sn = power(I_b, n), power(sigma_b, n)
    return (
        power(delta / R_max, (n - 1.0) / n)
        * (In + sn) ** 2
        / (power(I_b, n - 1.0) * sn * sigma_dark)
    )
