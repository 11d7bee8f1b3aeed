"""The proof's views of a recording, read by the source that reads its layout.

Apart from `prove_read` (the bag reader and the views' types) so that the readers, which the
sources call (`RecordingSource.proof_data`), never import the registry that imports the
sources.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.sources.registry import source_for
from pipeline.inspect.model import Inspection
from pipeline.inspect.prove_read import ProofData


def read_proof_data(ins: Inspection, lidars: list[str]) -> ProofData:
    """The proof's views of a recording inspected as `ins`, read by the source that reads its
    layout (`RecordingSource.proof_data`: bags here, `prove_hf`, `prove_kitti360`)."""
    path = Path(ins.path)
    src = source_for(path)
    if not hasattr(src, "proof_data"):  # a source registered before it could give them
        return ProofData(path, TfTree(), problems=[f"the {src.name} source cannot give the "
                                                   "proof's views yet"])  # fmt: skip
    return src.proof_data(path, ins, lidars)
