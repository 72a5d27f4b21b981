"""Static photoreceptor response: Naka-Rushton law, Hunt's sigma and bleaching.

Pure functions on arrays of any shape, float32 or float64 (they follow the
dtype of their inputs; lists and tuples are taken as arrays; a negative
luminance gives NaN). Luminance in cd/m2 (scotopic cd/m2 for rods),
responses dimensionless.

References
----------
Pattanaik, Tumblin, Yee, Greenberg (2000), *Time-Dependent Visual Adaptation
for Fast Realistic Image Display*, Eqs 1-6.
"""

import jax.numpy as jnp

from jaxadapt.physiology._inputs import array_like, nonnegative

__all__ = [
    "N_HUNT",
    "power",
    "naka_rushton",
    "naka_rushton_inverse",
    "log_naka_rushton_sum_inverse",
    "naka_rushton_sum_inverse",
    "response_slope",
    "forward_difference_slope",
    "hunt_F_L",
    "hunt_F_LS",
    "sigma_cone",
    "sigma_rod",
    "bleach_cone",
    "bleach_rod",
]

#: Response exponent of Hunt's model (Pattanaik 2000, §4.1.1).
N_HUNT = 0.73


@array_like
def power(x, p):
    """``x^p`` for ``x >= 0``, as ``exp(p ln x)``, with ``0^p = 0`` (``p > 0``).

    The same value as ``x ** p``, written this way because XLA's general
    ``pow`` (which handles negative bases and integer exponents) is several
    times slower than ``exp`` and ``log`` on the CPU, and the
    operators evaluate it several times per pixel. Zero gives zero with a
    zero gradient (no ``0 * inf``); a negative ``x``, outside the domain,
    gives NaN as NaN does, so that neither vanishes into a response of 0.

    Examples
    --------
    >>> round(float(power(8.0, 1 / 3)), 12), float(power(0.0, 0.73)), float(power(-1.0, 0.73))
    (2.0, 0.0, nan)
    """
    positive = x > 0
    safe = jnp.where(positive, x, 1.0)
    # NaN as an array of x's dtype, not a literal: Triton's lowering of a
    # Pallas kernel can take a NaN literal of a select for an integer
    # (jaxadapt.fused runs this inside such a kernel).
    outside = jnp.where(x == 0, jnp.zeros_like(safe), jnp.full_like(safe, jnp.nan))
    return jnp.where(positive, jnp.exp(p * jnp.log(safe)), outside)


@array_like
def naka_rushton(L, sigma, B=1.0, n=N_HUNT):
    """Naka-Rushton response ``R = B L^n / (L^n + sigma^n)`` (Eq 2).

    Parameters
    ----------
    L : array_like
        Luminance, cd/m2, ``>= 0``.
    sigma : array_like
        Semi-saturation luminance, cd/m2, ``> 0``.
    B : array_like
        Maximum response (pigment bleaching factor), in [0, 1].
    n : float
        Exponent.

    Returns
    -------
    array
        Response in ``[0, B)``. Written as ``B x / (1 + x)`` with
        ``x = (L / sigma)^n`` so that ``L = 0`` and ``L = 1e8`` are finite.

    Examples
    --------
    >>> float(naka_rushton(2.0, 2.0, B=0.5))
    0.25
    """
    x = power(L / sigma, n)
    return B * x / (1.0 + x)


@array_like
def naka_rushton_inverse(R, sigma, B=1.0, n=N_HUNT):
    """Luminance that evokes response ``R``: the inverse of Eq 2.

    ``L = sigma (R / (B - R))^(1/n)``, for ``0 <= R < B``.

    Parameters
    ----------
    R : array_like
        Response, in ``[0, B)``.
    sigma : array_like
        Semi-saturation luminance, cd/m2.
    B : array_like
        Maximum response.
    n : float
        Exponent.

    Returns
    -------
    array
        Luminance in cd/m2: ``inf`` at ``R = B``, NaN for ``R`` outside
        ``[0, B]`` (no luminance evokes it: ``R / (B - R)`` is negative,
        which :func:`power` takes to NaN).

    Examples
    --------
    >>> float(naka_rushton_inverse(0.25, 2.0, B=0.5))
    2.0
    """
    R = jnp.asarray(R)
    return sigma * power(R / (B - R), 1.0 / n)


def _in_range(R, B, value):
    """``value`` of an inverse response where ``0 <= R < B``, ``inf`` where
    ``R = B`` (saturation) and NaN elsewhere."""
    value = jnp.asarray(value)
    beyond = jnp.where(R == B, jnp.full_like(value, jnp.inf), jnp.full_like(value, jnp.nan))
    return jnp.where((R >= 0) & (R < B), value, beyond)  # (arrays, as in power)


@array_like
def log_naka_rushton_sum_inverse(R, sigma_1, B_1, sigma_2, B_2, n=N_HUNT):
    """Log of the luminance at which two Naka-Rushton responses with one exponent sum to ``R``.

    Solves ``R = B_1 x_1 / (1 + x_1) + B_2 x_2 / (1 + x_2)`` with
    ``x_i = (L / sigma_i)^n`` exactly: the display observer's ``R_rod +
    R_cone`` of Pattanaik et al. (2000), §4.3. With ``u = x_2`` and
    ``k = (sigma_1 / sigma_2)^n`` (so ``x_1 = u / k``), clearing the
    denominators gives the quadratic::

        (R - B_1 - B_2) u^2 + (R (k + 1) - B_1 - k B_2) u + R k = 0

    whose leading coefficient is negative and constant term non-negative
    for ``0 <= R < B_1 + B_2``, so it has exactly one root ``u >= 0``
    (the sum is increasing in ``u``). It is taken in the cancellation-free
    form of the quadratic formula; then ``ln L = ln sigma_2 + (ln u) / n``.

    The logarithm is the primary form because the operator's display path
    needs ``ln L``: forming ``L`` and taking its log again would cost an
    exponential and a log per pixel. A root at or below the smallest normal
    float (``R = 0`` gives ``u = 0``) enters as that float (``L`` 0 once
    exponentiated) with a zero gradient, through a select rather than
    ``log(max(u, tiny))``, whose compiled gradient is NaN at ``u = 0``.

    Parameters
    ----------
    R : array_like
        Summed response, in ``[0, B_1 + B_2)``.
    sigma_1, sigma_2 : array_like
        Semi-saturation luminances, cd/m2.
    B_1, B_2 : array_like
        Maximum responses.
    n : float
        Shared exponent.

    Returns
    -------
    array
        ``ln L``, L in cd/m2: ``inf`` at ``R = B_1 + B_2``, NaN for ``R``
        outside ``[0, B_1 + B_2]``.

    Examples
    --------
    >>> L = 30.0
    >>> R = naka_rushton(L, 722.0, 0.0016) + naka_rushton(L, 646.0, 1.0)
    >>> round(float(jnp.exp(log_naka_rushton_sum_inverse(R, 722.0, 0.0016, 646.0, 1.0))), 6)
    30.0
    """
    k = power(sigma_1 / sigma_2, n)
    a = R - B_1 - B_2
    b = R * (k + 1.0) - B_1 - k * B_2
    c = R * k
    q = -0.5 * (b + jnp.where(b >= 0, 1.0, -1.0) * jnp.sqrt(jnp.maximum(b * b - 4.0 * a * c, 0)))
    u = jnp.where(b >= 0, q / a, c / jnp.where(q == 0, 1.0, q))
    tiny = jnp.finfo(jnp.result_type(u)).tiny
    positive = u > tiny
    ln_u = jnp.where(positive, jnp.log(jnp.where(positive, u, 1.0)), jnp.log(tiny))
    return _in_range(R, B_1 + B_2, jnp.log(sigma_2) + ln_u / n)


@array_like
def naka_rushton_sum_inverse(R, sigma_1, B_1, sigma_2, B_2, n=N_HUNT):
    """Luminance (cd/m2) at which two Naka-Rushton responses sum to ``R``:
    ``exp`` of :func:`log_naka_rushton_sum_inverse` (0 for ``R = 0``).

    Examples
    --------
    >>> L = 30.0
    >>> R = naka_rushton(L, 722.0, 0.0016) + naka_rushton(L, 646.0, 1.0)
    >>> round(float(naka_rushton_sum_inverse(R, 722.0, 0.0016, 646.0, 1.0)), 6)
    30.0
    """
    return jnp.exp(log_naka_rushton_sum_inverse(R, sigma_1, B_1, sigma_2, B_2, n))


@array_like
def response_slope(L, sigma, B=1.0, n=N_HUNT):
    """Slope of Eq 2 per log10 unit of luminance: ``S = dR / dlog10(L)`` (Eq 3).

    The paper writes Eq 3 as a derivative with respect to ``log L`` and the
    display slope ``S_d = 0.1383`` as a forward difference per log10 unit
    (§4.3). We use log10 for both, so that the two exponents of the colour
    path (``S_color`` at the scene, ``1/S_d`` at the display) measure the
    same thing::

        S = ln(10) n B L^n sigma^n / (L^n + sigma^n)^2
          = ln(10) n B x / (1 + x)^2,   x = (L / sigma)^n.

    Parameters
    ----------
    L : array_like
        Luminance, cd/m2.
    sigma : array_like
        Semi-saturation luminance, cd/m2.
    B : array_like
        Maximum response.
    n : float
        Exponent.

    Returns
    -------
    array
        Response per log10 unit of luminance; largest, ``ln(10) n B / 4``,
        at ``L = sigma``.

    Examples
    --------
    >>> round(float(response_slope(1.0, 1.0, n=1.0)), 4)  # ln(10) / 4
    0.5756
    """
    x = power(L / sigma, n)
    return jnp.log(10.0) * n * B * x / (1.0 + x) ** 2


@array_like
def forward_difference_slope(L_white, L_black, sigma, B=1.0, n=N_HUNT):
    """Forward-difference slope of Eq 2 between two luminances, per log10 unit.

    This is how the paper sets the display's colour exponent ``S_d`` (§4.3):
    ``(R(L_white) - R(L_black)) / (log10 L_white - log10 L_black)``. With
    ``L_white = 125``, ``L_black = 125/32``, ``sigma = sigma_cone(25)`` and
    ``B = 1`` it gives the paper's ``S_d = 0.1383``.

    Examples
    --------
    >>> round(float(forward_difference_slope(125.0, 125.0 / 32, sigma_cone(25.0))), 4)
    0.1383
    """
    rise = naka_rushton(L_white, sigma, B, n) - naka_rushton(L_black, sigma, B, n)
    return rise / (jnp.log10(L_white) - jnp.log10(L_black))


@array_like
def hunt_F_L(A):
    """Hunt's luminance-level adaptation factor ``F_L`` for cones.

    ``F_L = 0.2 k^4 (5A) + 0.1 (1 - k^4)^2 (5A)^(1/3)``, ``k = 1 / (5A + 1)``,
    where ``5A`` is the luminance of Hunt's reference white for an adapting
    luminance ``A`` (cd/m2). Eq 5 of the paper is ``2^(1/n) 5A / F_L``.
    """
    k4 = (1.0 / (5.0 * A + 1.0)) ** 4
    return 0.2 * k4 * (5.0 * A) + 0.1 * (1.0 - k4) ** 2 * power(5.0 * A, 1.0 / 3.0)


@array_like
def hunt_F_LS(A):
    """Hunt's scotopic luminance-level adaptation factor ``F_LS`` (rods).

    ``F_LS = 3800 j^2 (5A) + 0.2 (1 - j^2)^4 (5A)^(1/6)``,
    ``j = 1 / (5e5 A + 1)``, with ``A`` in scotopic cd/m2. This is the
    denominator of Eq 4 (``19000 = 5 * 3800``, ``0.2615 = 0.2 * 5^(1/6)``)
    with Hunt's factor 1/2.26 dropped as the paper does. The exponent 4 of
    ``(1 - j^2)`` and the constant 5e5 of ``j`` are the paper's (Eq 4); some
    implementations use 5e4 (pfstmo) or an exponent 0.4 (colour-science).
    They agree only in the photopic range and diverge in scotopic light,
    where pfstmo's ``sigma_rod`` comes out about half of ours.
    """
    j2 = (1.0 / (5e5 * A + 1.0)) ** 2
    return 3800.0 * j2 * (5.0 * A) + 0.2 * (1.0 - j2) ** 4 * power(5.0 * A, 1.0 / 6.0)


def _semi_saturation(F, A, n, dark_gain):
    """``2^(1/n) 5A / F(A)`` (Eqs 4-5) for a Hunt factor ``F`` with
    ``F(A) -> dark_gain 5A`` as ``A -> 0``, and that limit,
    ``2^(1/n) / dark_gain``, at ``A = 0`` itself, where the quotient is 0/0.

    Darkness is a state the eye adapts to, and Hunt's factors are linear
    in ``A`` near it (``k, j -> 1``), so the semi-saturation has a finite
    dark value. Its gradient at ``A = 0`` is taken as 0.
    """
    dark = A == 0
    safe = jnp.where(dark, 1.0, A)
    return 2.0 ** (1.0 / n) * jnp.where(dark, 1.0 / dark_gain, 5.0 * safe / F(safe))


@array_like
def sigma_cone(A, n=N_HUNT):
    """Cone semi-saturation luminance for adaptation ``A`` (Eq 5).

    ``sigma_cone = 2^(1/n) 5A / F_L(A)``, which with ``n = 0.73`` is the
    paper's ``12.9223 A / (k^4 A + 0.171 (1 - k^4)^2 A^(1/3))``: where
    Hunt's ``f_n(F_L L / 5A)``, whose argument is luminance relative to his
    reference white ``5A``, reaches half its maximum (``(F_L L / 5A)^n =
    2``). ``sigma_cone(25) = 646`` cd/m2 (paper, display table).

    Parameters
    ----------
    A : array_like
        Cone adaptation luminance, cd/m2, ``>= 0``.

    Returns
    -------
    array
        Semi-saturation luminance, cd/m2; at ``A = 0`` its dark limit
        ``2^(1/n) / 0.2 = 12.92`` cd/m2 (:func:`_semi_saturation`).
    """
    return _semi_saturation(hunt_F_L, A, n, dark_gain=0.2)


@array_like
def sigma_rod(A, n=N_HUNT):
    """Rod semi-saturation luminance for adaptation ``A`` (Eq 4).

    ``sigma_rod = 2^(1/n) 5A / F_LS(A)``.

    Notes
    -----
    Eq 4 as printed has the numerator ``2.5874 A``, which is ``2^(1/n) A``
    without the factor 5 of reference white that Eq 5 carries
    (``12.9223 = 5 * 2^(1/n)``). At 25 cd/m2 the printed form gives 145
    cd/m2, while the paper's own display table lists ``sigma_rod = 722``
    cd/m2; ``12.9223 A / (...)`` gives 722.4. We follow the table and the
    structure of Eq 5 (both derive sigma from reference white ``5A``), and
    read the printed 2.5874 as a typesetting slip.

    Parameters
    ----------
    A : array_like
        Rod adaptation luminance, scotopic cd/m2, ``>= 0``.

    Returns
    -------
    array
        Semi-saturation luminance, scotopic cd/m2; at ``A = 0`` its dark
        limit ``2^(1/n) / 3800 = 6.8e-4`` cd/m2 (:func:`_semi_saturation`).
    """
    return _semi_saturation(hunt_F_LS, A, n, dark_gain=3800.0)


@array_like
def bleach_cone(A):
    """Hunt's static cone bleaching factor ``B = 2e6 / (2e6 + A)`` (Eq 6).

    Parameters
    ----------
    A : array_like
        Cone adaptation luminance, cd/m2.

    Returns
    -------
    array
        Fraction of unbleached pigment, in (0, 1]; NaN where ``A < 0``.
    """
    return nonnegative(A, 2e6 / (2e6 + A))


@array_like
def bleach_rod(A):
    """Hunt's static rod bleaching factor ``B = 0.04 / (0.04 + A)`` (Eq 6).

    ``bleach_rod(25) = 0.0016`` (paper, display table).

    Parameters
    ----------
    A : array_like
        Rod adaptation luminance, scotopic cd/m2.

    Returns
    -------
    array
        Fraction of unbleached pigment, in (0, 1]; NaN where ``A < 0``.
    """
    return nonnegative(A, 0.04 / (0.04 + A))
