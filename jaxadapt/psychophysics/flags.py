"""Flags of degenerate psychometric data, and how the fit keeps them finite.

A dataset whose levels do not determine a cumulative Gaussian still gets a
finite fit from :func:`jaxadapt.psychophysics.psychometric.fit`: no output is
ever NaN. The data flags (bits of ``Fit.flags``) say what the data leave open:

| flag | bit | meaning |
| --- | --- | --- |
| ``ALL_SAME`` | 1 | every response is "yes", or every one "no" |
| ``SEPARATION`` | 2 | the levels separate yes from no responses, completely or quasi-completely |
| ``SINGLE_LEVEL`` | 4 | fewer than two distinct levels have trials |
| ``EXTRAPOLATED`` | 8 | the PSE lies outside the tested levels |
| ``FLAT`` | 16 | the slope is (numerically) zero |

With ``ALL_SAME``, ``SEPARATION`` or ``SINGLE_LEVEL`` the maximum-likelihood
estimate does not exist (or is not unique); those datasets are fitted with a
weak Gaussian prior, standard deviation :data:`PRIOR_SD`, on the
standardised intercept and slope, which gives finite estimates (a steep but
finite slope under separation) and a positive-definite information matrix.
The PSE and sigma are computed with the standardised slope kept at least
:data:`MIN_SLOPE` in magnitude (``FLAT`` is set when that bound is used), so
that a flat function gives a very large but finite PSE. A flat function
counts as increasing, as a psychometric function of the test level is:
every response "no" puts the PSE far above the tested levels and every one
"yes" far below them, on the side the data imply (the slope of such data is
0 at the optimum, and is set to 0: the solver leaves it within its
tolerance, whose sign would otherwise pick the side, and a group test would
rank the participant at either end). ``EXTRAPOLATED`` PSEs are returned, as
Jacobs et al. (2015), §4.1.2, does for its participant 11, and flagged.
"""

__all__ = [
    "ALL_SAME",
    "SEPARATION",
    "SINGLE_LEVEL",
    "EXTRAPOLATED",
    "FLAT",
    "FLAG_NAMES",
    "NO_MLE",
    "NO_PSE",
    "PRIOR_SD",
    "MIN_SLOPE",
    "flag_names",
]

ALL_SAME = 1
SEPARATION = 2
SINGLE_LEVEL = 4
EXTRAPOLATED = 8
FLAT = 16
#: Names of the flag bits, in bit order.
FLAG_NAMES = {
    ALL_SAME: "all_same",
    SEPARATION: "separation",
    SINGLE_LEVEL: "single_level",
    EXTRAPOLATED: "extrapolated",
    FLAT: "flat",
}
#: Flags under which the maximum-likelihood estimate does not exist.
NO_MLE = ALL_SAME | SEPARATION | SINGLE_LEVEL
#: Flags under which the data place no PSE: it is set by the prior and the
#: least slope (under separation it still lies between two levels).
NO_PSE = ALL_SAME | SINGLE_LEVEL | FLAT

#: Standard deviation of the weak Gaussian priors: on the standardised
#: intercept and slope when the MLE does not exist (``NO_MLE``), and on the
#: logit ``u`` of fitted rates.
PRIOR_SD = 10.0
#: Smallest standardised slope |b1 s| used for the PSE and sigma (``FLAT``).
MIN_SLOPE = 1e-6


def flag_names(flags):
    """Names of the bits set in one integer flag value.

    >>> flag_names(SEPARATION | EXTRAPOLATED)
    ('separation', 'extrapolated')
    """
    return tuple(name for bit, name in FLAG_NAMES.items() if int(flags) & bit)
