"""``python -m depthmocap.train.evaluation.protocol_halves``: a protocol's recordings as two
halves that ``dev_benchmark`` runs in parallel, one per core.

A broad-protocol run takes ~25 minutes on one core; its two halves in two processes, half
that. Each half is a folder of symbolic links to the recordings (nothing is copied), its own
``manifest.json`` (the recordings it holds, their frame count) and the protocol's
``protocol.yaml``, so ``dev_benchmark --protocol broad --recordings HALF`` runs it as it runs
the whole. The halves alternate over the manifest (its 1st, 3rd, ... recording in the first),
so each holds every motion class, body and view of the protocol; ``compare_runs`` pools the
two runs' figures frame-weighted, the same as one run over all of them.

    python -m depthmocap.train.evaluation.protocol_halves data/dev_broad \\
        --out data/broad_half_a data/broad_half_b
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

__all__ = ["ProtocolHalvesError", "split_protocol", "main"]


class ProtocolHalvesError(ValueError):
    """A folder that is not a protocol's (no manifest, a recording missing), or an output
    that already holds something else."""


def _link(target: Path, link: Path) -> None:
    """``link`` -> ``target`` (absolute), unless it is that link already."""
    if link.is_symlink() and link.resolve() == target.resolve():
        return
    if link.exists() or link.is_symlink():
        raise ProtocolHalvesError(f"{link} exists and is not a link to {target}")
    link.symlink_to(target.resolve(), target_is_directory=True)


def split_protocol(source: Path, outputs: tuple[Path, Path]) -> list[int]:
    """Split the protocol folder ``source`` (``manifest.json`` listing its ``recordings``,
    each a subfolder by ``name``, and ``protocol.yaml`` when there is one) into the two
    ``outputs`` (module docstring). Running it again on the same folders changes nothing.

    Returns:
        the number of recordings in each half.
    """
    try:
        manifest = json.loads((source / "manifest.json").read_text())
        recordings = manifest["recordings"]
        names = [r["name"] for r in recordings]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ProtocolHalvesError(
            f"{source}: no readable manifest.json with recordings ({err})"
        ) from err
    missing = [name for name in names if not (source / name).is_dir()]
    if missing:
        raise ProtocolHalvesError(f"{source}: recordings missing: {', '.join(missing[:5])}")
    counts = []
    for k, out in enumerate(outputs):
        half = recordings[k::2]
        out.mkdir(parents=True, exist_ok=True)
        for rec in half:
            _link(source / rec["name"], out / rec["name"])
        sub = {**manifest, "recordings": half}
        if "frames" in manifest:
            sub["frames"] = sum(int(r.get("frames", 0)) for r in half)
        (out / "manifest.json").write_text(json.dumps(sub, indent=1) + "\n")
        if (source / "protocol.yaml").is_file():
            shutil.copyfile(source / "protocol.yaml", out / "protocol.yaml")
        counts.append(len(half))
    return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.protocol_halves",
        description="Split a protocol's recordings into two halves (links and sub-manifests) "
        "that dev_benchmark runs in parallel.",
    )
    parser.add_argument("source", type=Path, help="the protocol's folder (e.g. data/dev_broad)")
    parser.add_argument(
        "--out", nargs=2, type=Path, required=True, metavar=("HALF_A", "HALF_B"),
        help="the two folders to write",
    )  # fmt: skip
    args = parser.parse_args(argv)
    try:
        counts = split_protocol(args.source, tuple(args.out))
    except ProtocolHalvesError as err:
        print(f"protocol_halves: {err}", file=sys.stderr)
        return 2
    for out, n in zip(args.out, counts, strict=True):
        print(f"{out}: {n} recordings")
    return 0


if __name__ == "__main__":
    sys.exit(main())
