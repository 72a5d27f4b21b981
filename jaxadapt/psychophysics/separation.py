"""What psychometric data whose levels separate the responses still say.

Where every "no" lies at or below every "yes" (or the reverse), no
maximum-likelihood fit exists (:data:`jaxadapt.psychophysics.flags.SEPARATION`):
the data say only that the PSE lies in the gap between the two
(:func:`separating_gap`) and that sigma is small (:func:`sigma_bound`).
:func:`undetermined` tells the groups whose data do not determine the fit.
"""

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.special import log_ndtr

from jaxadapt.psychophysics.flags import FLAT, NO_MLE, NO_PSE, SEPARATION

__all__ = ["undetermined", "SIGMA_BOUND_LEVEL", "sigma_bound", "separating_gap"]


def undetermined(flags):
    """Groups (by their fit's ``flags``) whose data do not determine the
    fit: no maximum-likelihood estimate exists (every response the same,
    separation, one level: :data:`~jaxadapt.psychophysics.flags.NO_MLE`), or
    the slope is zero (``FLAT``), which places no PSE."""
    return (np.asarray(flags) & (NO_MLE | FLAT)) > 0


#: Confidence of :func:`sigma_bound`, and the drop of the log-likelihood
#: that bounds it: half the chi-squared quantile of one degree of freedom.
SIGMA_BOUND_LEVEL = 0.95
_SIGMA_DROP = 0.5 * 3.841458820694124


def sigma_bound(levels, n_yes, n_total):
    """The largest spread ``sigma`` (log10 units) that data whose levels
    separate the responses do not reject at :data:`SIGMA_BOUND_LEVEL`: the
    profile likelihood's bound (the log-likelihood, maximised over the PSE,
    within ``chi2(1) / 2`` of its supremum, reached as sigma goes to 0);
    ``inf`` when no sigma is rejected (too few trials)."""
    x, k, n = (np.asarray(a, float) for a in (levels, n_yes, n_total))
    x, k, n = x[n > 0], k[n > 0], n[n > 0]
    if np.sum(k * x) / max(np.sum(k), 1e-300) < np.sum((n - k) * x) / max(np.sum(n - k), 1e-300):
        x = -x  # a falling function: its mirror image rises
    span = max(np.ptp(x), 1e-3)

    def profile(sigma):
        def nll(pse):
            z = (x - pse) / sigma
            return -np.sum(k * log_ndtr(z) + (n - k) * log_ndtr(-z))

        lo, hi = x.min() - 10 * sigma - span, x.max() + 10 * sigma + span
        return -minimize_scalar(nll, bounds=(lo, hi), method="bounded").fun

    target = profile(1e-9 * span) - _SIGMA_DROP
    largest = 1e3 * span
    if profile(largest) >= target:
        return np.inf
    log_sigma = brentq(
        lambda u: profile(np.exp(u)) - target, np.log(1e-9 * span), np.log(largest), xtol=1e-10
    )
    return float(np.exp(log_sigma))


def separating_gap(groups):
    """Per group, the levels ``(low, high)`` between which the responses
    change: the highest level with a "no" and the lowest with a "yes" when
    every "no" lies at or below every "yes", the reverse for a falling
    function; where neither holds, ``(-inf, inf)``. Under separation
    (:data:`jaxadapt.psychophysics.flags.SEPARATION`) the PSE lies in it."""
    x, k, n = groups.levels, groups.n_yes, groups.n_total
    yes, no = (n > 0) & (k > 0), (n > 0) & (k < n)
    top = [np.max(np.where(m, x, -np.inf), axis=1) for m in (no, yes)]
    bottom = [np.min(np.where(m, x, np.inf), axis=1) for m in (yes, no)]
    rising, falling = top[0] <= bottom[0], top[1] <= bottom[1]
    low = np.where(rising, top[0], np.where(falling, top[1], -np.inf))
    high = np.where(rising, bottom[0], np.where(falling, bottom[1], np.inf))
    return low, high


def _at_least_the_data(groups, flags, low, high):
    """The PSE interval ``(low, high)`` widened to what the data leave
    open: the separating gap under separation, everything where they place
    no PSE (:func:`fit_groups`)."""
    low, high = np.asarray(low), np.asarray(high)
    gap_low, gap_high = (g.astype(low.dtype) for g in separating_gap(groups))
    separated = (flags & SEPARATION) > 0
    unplaced = (flags & NO_PSE) > 0
    low = np.where(separated, np.minimum(low, gap_low), low)
    high = np.where(separated, np.maximum(high, gap_high), high)
    return np.where(unplaced, -np.inf, low), np.where(unplaced, np.inf, high)
