"""The hybrid's profile: torch operators and the launch/sync counts, on the CPU here."""

from __future__ import annotations

from depthmocap.bench.profile_hybrid import main, profile_hybrid


def test_profile_counts_the_hybrids_operators(one_thread):
    events = profile_hybrid("demo", "cpu", frames=2, warmup=1)
    counts = {e.key: e.count for e in events}
    # A tracked frame runs the solver: batched matrix products and indexing, many of each.
    assert counts.get("aten::bmm", 0) > 10
    assert counts.get("aten::index", 0) > 10


def test_the_command_prints_the_per_frame_counts_and_a_table(one_thread, capsys):
    main(["--frames", "1", "--rows", "3", "--threads", "1"])
    out = capsys.readouterr().out
    assert "kernel launches per frame: 0" in out  # none on the CPU
    assert "Self CPU time total" in out
