"""The own-map refit: a pair without an off-road map from the previous pair (the first
pair; after a failed or unusual fit, beyond ``map_carry``) maps its frame A from its own
fit (`OffroadMapper.map` run backward) and fits again without those pixels (``own_map``).

The first fit's noise scale may well be unusual: the raised structure the map would
remove is in it (waiting for a usual fit would lock the map out). A poor fit too: a
vehicle close behind fills the road with motion the road's model cannot fit
(rectilinear merge, frames 90-108).
"""

from __future__ import annotations

from collections.abc import Callable

from estimator.egomotion.coarse_to_fine import Fit
from estimator.egomotion.iekf import IteratedEKF


def own_map_refit(
    ekf: IteratedEKF,
    res: Fit,
    failure: tuple[str, str] | None,
    refit: Callable[[], Fit],
    fit_failure: Callable[[Fit], tuple[str, str] | None],
) -> tuple[Fit, tuple[str, str] | None, bool]:
    """(fit, its failure, whether it is the refit) after the first fit res with its
    failure, the filter at its estimate.

    refit(): a coarse-to-fine pass from the filter's prior without the own map's pixels;
    fit_failure(fit): its failure. The map takes out what did not fit: the refit is kept
    when it does not fail and fits at least as well (noise scale). A worse one says the
    first fit was off and its map took the road itself out (merge-omni-near frame 1: a
    fit at the CAN's +8 % marked 3/4 of the points, the refit on the rest went to +32 % at
    a higher noise scale); the first fit is then returned as it was, the filter at it.
    """
    first = res, ekf.x.copy(), ekf.P.copy(), failure
    res = refit()
    failure = fit_failure(res)
    if failure is None and res["noise_scale"] <= first[0]["noise_scale"]:
        return res, failure, True
    # (the map left too few points, or a worse fit): the first fit, as it was
    res, ekf.x, ekf.P, failure = first
    return res, failure, False
