"""Build the anny body model once so that later runs load it from the cache.

Called by the project's setup. The first build takes 40-80 s and writes up to 0.8 GB under
``$ANNY_CACHE_DIR`` (default ``<repo>/.cache/anny``, git-ignored); later it takes about 2 s.

Usage: ``python scripts/build_anny_cache.py [--topology anny]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a plain checkout too

from depthmocap.train.bodies.anny_body import DEFAULT_TOPOLOGY, default_cache_dir, load_anny_model  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--topology", default=DEFAULT_TOPOLOGY, help="anny topology name")
    args = parser.parse_args(argv)
    start = time.perf_counter()  # includes importing torch and anny (about 2 s)
    try:
        import anny  # noqa: F401
    except ImportError:
        print("build_anny_cache: anny is not installed (pip install '.[train]')", file=sys.stderr)
        return 1
    model = load_anny_model(topology=args.topology)
    seconds = time.perf_counter() - start
    print(
        f"build_anny_cache: anny rig=cmu_mb topology={args.topology}: "
        f"{model.template_vertices.shape[0]} vertices, {model.faces.shape[0]} faces, "
        f"{len(model.bone_labels)} bones; ready in {seconds:.1f} s (cache {default_cache_dir()})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
