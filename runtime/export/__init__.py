"""Tracking outputs (DESIGN.md): ``poses.jsonl``, ``motion.bvh``, ``summary.json``, ``body.json``.

:class:`ResultWriter` is what the tracking CLI uses; the modules below it are usable alone
(e.g. :func:`write_bvh` to convert stored poses).
"""

from .bvh import BvhWriter, write_bvh
from .poses_jsonl import PosesData, PosesFileError, PosesJsonlWriter, read_poses_jsonl
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
