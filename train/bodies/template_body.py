"""``python -m depthmocap.train.bodies.template_body``: the calibration template, the average body
of the training population measured on its meshes like every ground-truth body.

Skeleton calibration (``runtime-calibrate``, Wei section 6) scales a template's proportions
by what it measures. The built-in average adult (``BodyShape.default``) has rounded
anthropometric proportions, but the joints the system reports are anny's (the base of the neck,
the top of the lumbar spine, ...): from anny's spine joint to the neck is 32 cm on the dev
bodies where the default says 22, and a consensus scale cannot fix a proportion. This averages
the measured skeleton bodies (:func:`train.bodies.posing.skeleton_body_of`) of ``--count``
random training-population bodies (``train.bodies.anny_body.sample_phenotype``, a seed of its
own) and writes the body file that ``runtime-calibrate`` loads by default.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.resources import CONFIGS_DIR

__all__ = ["average_body", "population_template", "main"]

DEFAULT_OUT = CONFIGS_DIR / "body_template.json"


def average_body(bodies: list[BodyShape]) -> BodyShape:
    """Field-wise mean of unbatched bodies (lengths, radii, ..., clavicle rest)."""
    if not bodies:
        raise ValueError("no bodies to average")
    fields = zip(*(b.to(torch.float64)._fields() for b in bodies))
    body = BodyShape(*(torch.stack(list(f)).mean(0) for f in fields))
    body.validate()
    return body


def population_template(count: int, seed: int) -> BodyShape:
    """Average measured skeleton body of ``count`` random anny bodies."""
    from depthmocap.train.bodies.anny_body import make_body, sample_phenotype
    from depthmocap.train.bodies.posing import skeleton_body_of

    rng = np.random.default_rng([seed, 4409])
    return average_body(
        [skeleton_body_of(make_body(sample_phenotype(rng))) for _ in range(count)]
    ).to(torch.float32)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="train-template-body", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="body file to write")
    p.add_argument("--count", type=int, default=100, help="random bodies averaged")
    p.add_argument("--seed", type=int, default=0, help="seed of the body sampling")
    args = p.parse_args(argv)
    if args.count < 1:
        print("error: --count must be >= 1", file=sys.stderr)
        return 2
    body = population_template(args.count, args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    body.save(args.out)
    lengths = ", ".join(f"{x * 100:.1f}" for x in body.lengths.tolist())
    print(f"wrote {args.out}: stature {float(body.stature()) * 100:.1f} cm, lengths (cm) {lengths}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
