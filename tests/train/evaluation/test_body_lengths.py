"""Bone-length errors of estimated bodies against reference bodies (issue 6's calibration
target): golden values on scaled bodies, pairing, and bad input."""

from __future__ import annotations

import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.train.evaluation.body_lengths import bone_length_errors, format_bone_length_errors


def _save(body: BodyShape, path):
    path.parent.mkdir(parents=True, exist_ok=True)
    body.save(path)
    return path


def test_golden_values_on_scaled_bodies(tmp_path):
    ref = BodyShape.default(torch.float64)
    lengths = ref.lengths.numpy()
    refs = [_save(ref, tmp_path / f"ref{i}" / "body.json") for i in range(2)]
    # Body files are read in float32: golden values to 1e-4 cm.
    # Body 0 is exact; body 1 is 10% longer everywhere, so each bone is off by 10% of itself.
    est = [
        _save(ref, tmp_path / "a" / "body.json"),
        _save(ref.scaled(1.1), tmp_path / "b" / "body.json"),
    ]
    err = bone_length_errors(est, refs)
    assert err["bodies"] == 2
    assert err["per_body_cm"][0] == 0.0
    assert err["per_body_cm"][1] == pytest.approx(10.0 * lengths.mean(), abs=1e-3)
    assert err["mean_cm"] == pytest.approx(5.0 * lengths.mean(), abs=1e-4)
    assert err["max_cm"] == pytest.approx(10.0 * lengths.max(), abs=1e-4)
    thigh = sk.SEGMENT_NAMES.index("l_thigh")
    assert err["per_segment_cm"]["l_thigh"] == pytest.approx(5.0 * lengths[thigh], abs=1e-3)
    # The shape fields: body 1's are 10% larger too.
    for field in ("radii", "offsets", "feet"):
        size = getattr(ref, field).abs().numpy().mean()
        assert err["shape_mean_cm"][field] == pytest.approx(5.0 * size, rel=1e-4, abs=1e-5)
    hip = float(ref.hip_half_width)
    assert err["shape_mean_cm"]["hip_half_width"] == pytest.approx(5.0 * hip, abs=1e-4)
    text = format_bone_length_errors("calibrated", err)
    assert f"radii {err['shape_mean_cm']['radii']:.2f}" in text
    assert text.startswith("calibrated bodies (2): bone lengths ")
    assert f"{err['mean_cm']:.2f} cm off on average" in text


def test_bad_input_is_named(tmp_path):
    ref = _save(BodyShape.default(torch.float64), tmp_path / "ref.json")
    with pytest.raises(ValueError, match="matching, non-empty"):
        bone_length_errors([ref], [])
    with pytest.raises(ValueError, match="matching, non-empty"):
        bone_length_errors([], [])
    with pytest.raises(FileNotFoundError, match="missing.json"):
        bone_length_errors([tmp_path / "missing.json"], [ref])
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json"):
        bone_length_errors([bad], [ref])
