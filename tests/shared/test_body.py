import json

import numpy as np
import pytest
import torch
from depthmocap.shared.body import BodyShape


def test_default_stature_is_adult():
    assert 1.65 < float(BodyShape.default().stature()) < 1.85


def test_body_file_round_trip(tmp_path):
    body = BodyShape.default(torch.float64).scaled(1.1)
    body.save(tmp_path / "body.json")
    back = BodyShape.load(tmp_path / "body.json", torch.float64)
    for a, b in zip(body._fields(), back._fields()):
        assert torch.allclose(a, b)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.update(format="other"), "not a body file"),
        (lambda d: d.update(version=99), "version 99 is not supported"),
        (lambda d: d["segments"].pop("head"), "lacks segments: head"),
        (lambda d: d["segments"]["head"].update(length=-1.0), "must be positive"),
        (lambda d: d["segments"]["head"].update(radii="x"), "malformed"),
    ],
)
def test_malformed_body_files(tmp_path, mutate, message):
    data = BodyShape.default().to_json_dict()
    mutate(data)
    (tmp_path / "b.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=message):
        BodyShape.load(tmp_path / "b.json")


def test_body_file_not_json(tmp_path):
    (tmp_path / "b.json").write_bytes(b"\x00\x01garbage")
    with pytest.raises(ValueError, match="not valid JSON"):
        BodyShape.load(tmp_path / "b.json")
    with pytest.raises(FileNotFoundError, match="body file not found"):
        BodyShape.load(tmp_path / "missing.json")


def test_body_file_keeps_offsets_and_feet(tmp_path):
    body = BodyShape.default(torch.float64)
    body.offsets[1] = torch.tensor([0.0, 0.06])
    body.feet = torch.tensor([[0.21, 0.03], [0.2, 0.031]], dtype=torch.float64)
    body.chest_tilt = torch.tensor(0.17, dtype=torch.float64)
    body.clavicle_rest = torch.tensor([-0.38, 0.12], dtype=torch.float64)
    body.save(tmp_path / "body.json")
    back = BodyShape.load(tmp_path / "body.json", torch.float64)
    assert torch.allclose(back.offsets, body.offsets) and torch.allclose(back.feet, body.feet)
    assert float(back.chest_tilt) == pytest.approx(0.17)
    np.testing.assert_allclose(back.clavicle_rest.numpy(), [-0.38, 0.12])
    data = body.to_json_dict()
    data["version"] = 3  # version 3 had no clavicle rest: horizontal clavicles
    del data["clavicle_rest"]
    assert BodyShape.from_json_dict(data).clavicle_rest.tolist() == [0.0, 0.0]
    for bad in ([1.2, 0.0], [0.1], "x"):
        data["clavicle_rest"] = bad
        with pytest.raises(ValueError, match="clavicle_rest|malformed"):
            BodyShape.from_json_dict(data)
    del data["clavicle_rest"]
    data["version"] = 2  # version 2 had no tilt: an upright chest
    del data["chest_tilt"]
    assert float(BodyShape.from_json_dict(data).chest_tilt) == 0.0
    data["chest_tilt"] = 2.0
    with pytest.raises(ValueError, match="chest_tilt"):
        BodyShape.from_json_dict(data)


def test_version_1_body_file_loads_with_centred_sections_and_scaled_feet(tmp_path):
    data = BodyShape.default().scaled(1.1).to_json_dict()
    data["version"] = 1
    for seg in data["segments"].values():
        seg.pop("offsets")
        seg.pop("foot", None)
    (tmp_path / "v1.json").write_text(json.dumps(data))
    body = BodyShape.load(tmp_path / "v1.json", torch.float64)
    assert float(body.offsets.abs().max()) == 0.0
    # Default feet, scaled like the body (stature 1.1 times the default's).
    assert torch.allclose(body.feet, BodyShape.default(torch.float64).feet * 1.1, atol=1e-6)


def test_editing_a_default_body_leaves_the_defaults_alone():
    body = BodyShape.default(torch.float64)
    body.lengths[5] = 0.5
    body.radii[0, 0] = 0.5
    fresh = BodyShape.default(torch.float64)
    assert float(fresh.lengths[5]) != 0.5 and float(fresh.radii[0, 0]) != 0.5


def test_select_takes_bodies_of_a_batch():
    body = BodyShape.default()
    batch = body.scaled(torch.tensor([0.9, 1.0, 1.1, 1.2]))
    part = batch.select(slice(1, 3))
    assert part.lengths.shape == (2, body.lengths.shape[0])
    torch.testing.assert_close(part.lengths, batch.lengths[1:3])
    torch.testing.assert_close(part.feet, batch.feet[1:3])
    assert torch.equal(part.chest_tilt, batch.chest_tilt)  # unbatched in a scaled batch: shared
    torch.testing.assert_close(part.stature(), batch.stature()[1:3])
    with pytest.raises(ValueError, match="batch of bodies"):
        body.select(slice(0, 1))


def test_girthed_widens_the_sections_and_keeps_the_lengths():
    """Radii, cross-section offsets and the hip half-width scale; lengths, end caps, feet and
    so the stature stay; a (N,) factor on a batch of N widens each body by its own."""
    body = BodyShape.default(torch.float64)
    body.offsets = body.offsets + 0.01  # non-zero offsets, so their scaling is seen
    wide = body.girthed(1.2)
    torch.testing.assert_close(wide.radii, 1.2 * body.radii)
    torch.testing.assert_close(wide.offsets, 1.2 * body.offsets)
    torch.testing.assert_close(wide.hip_half_width, 1.2 * body.hip_half_width)
    for same in ("lengths", "extents", "feet", "chest_tilt", "clavicle_rest"):
        assert torch.equal(getattr(wide, same), getattr(body, same))
    torch.testing.assert_close(wide.stature(), body.stature())
    batch = body.scaled(torch.tensor([0.9, 1.1], dtype=torch.float64))
    widened = batch.girthed(torch.tensor([1.0, 1.3], dtype=torch.float64))
    torch.testing.assert_close(widened.radii[0], batch.radii[0])
    torch.testing.assert_close(widened.radii[1], 1.3 * batch.radii[1])
    torch.testing.assert_close(
        widened.hip_half_width, batch.hip_half_width * torch.tensor([1.0, 1.3], dtype=torch.float64)
    )
