"""A COLMAP reconstruction from ctxmatch's matches registers the images of a real six-image sequence.

Skipped without ``CTXMATCH_DATA`` (the shared real data) or without pycolmap (the test extras pin it).
"""

import itertools
import os
from pathlib import Path

import pytest

SEQUENCE = Path("planar") / "hpatches" / "v_churchill"


@pytest.mark.slow
@pytest.mark.realdata
def test_reconstruction_from_ctxmatch_matches_registers_the_sequence(tmp_path):
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap not installed (it is in the test extras)")
    root = os.environ.get("CTXMATCH_DATA")
    if not root or not (Path(root) / SEQUENCE).is_dir():
        pytest.skip(f"needs the real data: CTXMATCH_DATA with {SEQUENCE}")
    from ctxmatch_lib.io.export import write_colmap
    from ctxmatch_lib.match import match_images

    folder = Path(root) / SEQUENCE
    names = [f"{i}.ppm" for i in range(1, 7)]
    db = tmp_path / "database.db"
    for a, b in itertools.combinations(names, 2):
        r = match_images(folder / a, folder / b, filters=("dtm",), max_keypoints=2000,
                         cache_dir=tmp_path / "features")
        write_colmap(db, a, b, r.kpts1, r.kpts2, r.matches, image_size1=r.image_size1, image_size2=r.image_size2)
    pairs = tmp_path / "pairs.txt"
    pairs.write_text("".join(f"{a} {b}\n" for a, b in itertools.combinations(names, 2)))
    pycolmap.verify_matches(db, pairs)
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = 1
    options.random_seed = 0
    maps = pycolmap.incremental_mapping(db, folder, tmp_path / "sparse", options=options)
    assert maps, "COLMAP built no model from ctxmatch's matches"
    best = max(maps.values(), key=lambda rec: rec.num_reg_images())
    registered = sorted(im.name for im in best.images.values() if im.has_pose)
    assert registered == names
    assert best.num_points3D() > 500
