"""The filter registry offers the names the command line accepts."""

import numpy as np
import pytest

from ctxmatch_lib.dtm import dtm_filter
from ctxmatch_lib.evaluation import resolve_filters
from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import planted_homography_matches


@pytest.mark.parametrize("name", resolve_filters("all"))
def test_every_name_the_engine_accepts_is_in_the_registry(name):
    assert name in FILTERS and callable(FILTERS[name])


@pytest.mark.parametrize("name, stages", [("dtm1", 1), ("dtm2", 2)])
def test_dtm_stages_are_registry_names(name, stages):
    case = planted_homography_matches(n_matches=300, inlier_ratio=0.5, rng=3)
    kw = dict(image_size1=case.image_size, image_size2=case.image_size)
    keep = FILTERS[name](case.kpts1, case.kpts2, case.matches, case.scores, **kw)
    expected = dtm_filter(case.kpts1, case.kpts2, case.matches, case.scores, stages=stages, **kw)
    assert keep.dtype == bool and np.array_equal(keep, expected)
    assert keep.any() and case.is_inlier[keep].mean() > 0.9  # mostly the planted inliers
