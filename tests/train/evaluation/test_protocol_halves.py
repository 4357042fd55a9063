"""Splitting a protocol's recordings into two halves (train.evaluation.protocol_halves)."""

from __future__ import annotations

import json

import pytest
from depthmocap.train.evaluation.protocol_halves import ProtocolHalvesError, main, split_protocol


def _protocol(root, frames=(10, 20, 30, 40, 50)):
    """A protocol folder of len(frames) recordings (empty folders), its manifest and yaml."""
    src = root / "proto"
    src.mkdir()
    recs = []
    for k, n in enumerate(frames):
        (src / f"rec{k}").mkdir()
        (src / f"rec{k}" / "meta.json").write_text("{}")
        recs.append({"name": f"rec{k}", "frames": n, "motion_class": f"c{k % 2}"})
    manifest = {"protocol": "broad", "version": 1, "frames": sum(frames), "recordings": recs}
    (src / "manifest.json").write_text(json.dumps(manifest))
    (src / "protocol.yaml").write_text("seed: 37\n")
    return src


def test_halves_alternate_and_link_the_recordings(tmp_path):
    src = _protocol(tmp_path)
    a, b = tmp_path / "a", tmp_path / "b"
    assert split_protocol(src, (a, b)) == [3, 2]
    ma, mb = (json.loads((d / "manifest.json").read_text()) for d in (a, b))
    assert [r["name"] for r in ma["recordings"]] == ["rec0", "rec2", "rec4"]
    assert [r["name"] for r in mb["recordings"]] == ["rec1", "rec3"]
    assert (ma["frames"], mb["frames"]) == (90, 60) and ma["protocol"] == "broad"
    assert (a / "rec2").is_symlink() and (a / "rec2" / "meta.json").is_file()
    assert (b / "protocol.yaml").read_text() == "seed: 37\n"
    assert split_protocol(src, (a, b)) == [3, 2]  # again: nothing changes


def test_bad_input_is_a_clear_error(tmp_path, capsys):
    src = _protocol(tmp_path)
    with pytest.raises(ProtocolHalvesError, match="manifest"):
        split_protocol(tmp_path / "nowhere", (tmp_path / "a", tmp_path / "b"))
    nameless = tmp_path / "nameless"
    nameless.mkdir()
    (nameless / "manifest.json").write_text(json.dumps({"recordings": [{"frames": 3}]}))
    with pytest.raises(ProtocolHalvesError, match="manifest"):
        split_protocol(nameless, (tmp_path / "a", tmp_path / "b"))
    (src / "rec3" / "meta.json").unlink()
    (src / "rec3").rmdir()
    with pytest.raises(ProtocolHalvesError, match="rec3"):
        split_protocol(src, (tmp_path / "a", tmp_path / "b"))
    (src / "rec3").mkdir()
    taken = tmp_path / "a"
    (taken / "rec0").mkdir(parents=True)  # a real folder where a link would go
    assert main([str(src), "--out", str(taken), str(tmp_path / "b")]) == 2
    assert "rec0" in capsys.readouterr().err
