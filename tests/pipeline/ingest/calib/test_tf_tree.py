"""Static TF tree: inverted edges resolve, a missing edge fails naming the chain."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.ingest.calib.tf_tree import MissingTransformError, TfTree
from tests.pipeline.ingest.bagkit import STATIC_EDGES, gt_T_base


def _tree(skip: str | None = None) -> TfTree:
    tree = TfTree()
    for parent, child, T in STATIC_EDGES:
        if child != skip:
            tree.add(parent, child, T)
    return tree


@pytest.mark.parametrize("frame", ["box_base", "hdr_front", "hesai_lidar"])
def test_lookup_composes_and_inverts(frame: str) -> None:
    tree = _tree()
    np.testing.assert_allclose(tree.lookup("base", frame), gt_T_base(frame), atol=1e-12)
    np.testing.assert_allclose(
        tree.lookup(frame, "base") @ tree.lookup("base", frame), np.eye(4), atol=1e-12
    )


def test_missing_edge_names_the_chain() -> None:
    tree = _tree(skip="hdr_base")
    with pytest.raises(MissingTransformError, match=r"'base' to 'hdr_front'.*hdr_base"):
        tree.lookup("base", "hdr_front")
    with pytest.raises(MissingTransformError, match="appears in no transform"):
        tree.lookup("base", "nowhere")
