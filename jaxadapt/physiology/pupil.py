"""Pupil diameter as a function of the adapting luminance, and pupil area.

Pure functions on arrays of any shape that follow the dtype of their inputs
(lists and tuples are taken as arrays); a negative luminance or diameter
gives NaN.
Luminance in cd/m2, diameter in mm, area in mm2.

References
----------
Reinhard, Ward, Pattanaik, Debevec (2005), *High Dynamic Range Imaging*,
chapter 6, §6.2.1-6.2.2, after Moon and Spencer
(1944) and de Groot and Gebhard (1952), as given by Wyszecki and Stiles
(1982), *Color Science*, 2nd ed., p. 106.
"""

import jax.numpy as jnp

from jaxadapt.physiology._inputs import array_like, nonnegative

__all__ = [
    "DE_GROOT_GEBHARD_DARK",
    "diameter_moon_spencer",
    "diameter_de_groot_gebhard",
    "area",
    "DIAMETERS",
]

#: Luminance of the de Groot and Gebhard formula's largest pupil,
#: ``10^-8.6`` cd/m2 (where its cubic in log luminance has zero slope).
DE_GROOT_GEBHARD_DARK = 10.0**-8.6


@array_like
def diameter_moon_spencer(L):
    """Pupil diameter after Moon and Spencer: ``d = 4.9 - 3 tanh(0.4 (log10 L + 1))``.

    Parameters
    ----------
    L : array_like
        Adapting luminance, cd/m2, ``>= 0``.

    Returns
    -------
    array
        Diameter, mm, between 1.9 (bright) and 7.9 (dark); ``L = 0`` gives
        the dark limit 7.9 mm, with a zero derivative (luminance is floored
        at the dtype's smallest normal number, where the curve is flat to
        its precision); NaN where ``L < 0``.

    Notes
    -----
    The formula as the chapter and Wyszecki and Stiles give it. Watson and
    Yellott (2012), converting Moon and Spencer's blondels to cd/m2, find
    ``4.9 - 3 tanh(0.4 log10 L)``: the same curve one log unit higher on the
    luminance axis. We keep the chapter's constants; the spread between the
    published pupil formulas is larger than this.

    Examples
    --------
    >>> round(float(diameter_moon_spencer(0.1)), 6)
    4.9
    """
    L = jnp.asarray(L, jnp.result_type(L, float))
    floored = jnp.maximum(L, jnp.finfo(L.dtype).tiny)
    return nonnegative(L, 4.9 - 3.0 * jnp.tanh(0.4 * (jnp.log10(floored) + 1.0)))


@array_like
def diameter_de_groot_gebhard(L):
    """Pupil diameter after de Groot and Gebhard:
    ``log10 d = 0.8558 - 4.01e-4 (log10 L + 8.6)^3``.

    Parameters
    ----------
    L : array_like
        Adapting luminance, cd/m2, ``>= 0``.

    Returns
    -------
    array
        Diameter, mm; at most ``10^0.8558 = 7.18`` mm; NaN where ``L < 0``.

    Notes
    -----
    The cubic's slope is zero, at its inflection point, at ``L = 10^-8.6``
    cd/m2 (:data:`DE_GROOT_GEBHARD_DARK`); below it the polynomial would make the
    pupil grow without bound (and infinite at ``L = 0``), which is an
    artefact of the fit, not of the eye. We hold the diameter at its maximum
    there, so ``L = 0`` gives the dark-adapted 7.18 mm. Above about 300
    cd/m2 the formula falls below the 2 mm that the chapter gives as the
    smallest pupil (1.1 mm at 1e4 cd/m2); we leave that as published. As
    for :func:`diameter_moon_spencer`, Watson and Yellott (2012) place the
    curve one log unit higher (``7.597`` instead of ``8.6`` in cd/m2).

    Examples
    --------
    >>> round(float(diameter_de_groot_gebhard(0.0)), 3)
    7.175
    """
    x = jnp.log10(jnp.maximum(L, DE_GROOT_GEBHARD_DARK)) + 8.6
    return nonnegative(L, 10.0 ** (0.8558 - 4.01e-4 * x**3))


@array_like
def area(d):
    """Area of a circular pupil of diameter ``d``: ``pi d^2 / 4``.

    Parameters
    ----------
    d : array_like
        Diameter, mm.

    Returns
    -------
    array
        Area, mm2; NaN where ``d < 0``.

    Examples
    --------
    >>> round(float(area(2.0)), 6)
    3.141593
    """
    return nonnegative(d, 0.25 * jnp.pi * d**2)


#: Pupil-diameter formulas by name: luminance (cd/m2) to diameter (mm).
DIAMETERS = {"moon-spencer": diameter_moon_spencer, "de-groot-gebhard": diameter_de_groot_gebhard}
