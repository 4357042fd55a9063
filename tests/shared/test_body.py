import json

import pytest
import torch

from shared.body import BodyShape


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
