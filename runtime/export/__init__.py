"""Tracking outputs (DESIGN.md): ``poses.jsonl``, ``motion.bvh``, ``summary.json``, ``body.json``.

:class:`ResultWriter` is what the tracking CLI uses; the modules below it are usable alone
(e.g. :func:`write_bvh` to convert stored poses). The ``poses.jsonl`` format itself lives in
:mod:`shared.poses_format` (the evaluation reads it); its writer is re-exported here.
"""

from depthmocap.shared.poses_format import (
    PosesData,
    PosesFileError,
    PosesJsonlWriter,
    read_poses_jsonl,
)

from .bvh import BvhWriter, write_bvh
from .results import RESULT_FILES, ResultDirError, ResultWriter

__all__ = [
    "ResultWriter",
    "ResultDirError",
    "RESULT_FILES",
    "BvhWriter",
    "write_bvh",
    "PosesJsonlWriter",
    "PosesData",
    "PosesFileError",
    "read_poses_jsonl",
]
