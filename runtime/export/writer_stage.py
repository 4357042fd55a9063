"""A stage in front of a result writer (:class:`~runtime.export.results.ResultWriter`):
streaming (:class:`~runtime.export.live.LiveOutput`) and fixed-lag smoothing
(:class:`~runtime.export.fixed_lag.FixedLagSmoother`) take the same calls as the writer, so
the tracking loop does not know which stages it writes through. A stage changes
``write_frame`` (and what it needs to); the rest reaches the writer unchanged.
"""

from __future__ import annotations

__all__ = ["WriterStage"]


class WriterStage:
    """Delegates ``extra``, ``directory``, ``frames``, ``update_body``, ``note_estimated`` and
    ``close`` to
    ``self.writer`` (set by the subclass), and is its own context manager."""

    writer = None

    @property
    def extra(self) -> dict:
        """The writer's ``extra`` (what ``summary.json`` stores under that key)."""
        return self.writer.extra

    @property
    def directory(self):
        """Where the writer's files are now."""
        return self.writer.directory

    @property
    def frames(self) -> int:
        """Frames the writer has written so far."""
        return self.writer.frames

    def update_body(self, body) -> None:
        """As :meth:`ResultWriter.update_body`."""
        self.writer.update_body(body)

    def note_estimated(self) -> None:
        """As :meth:`ResultWriter.note_estimated` (a writer without it ignores the note)."""
        note = getattr(self.writer, "note_estimated", None)
        if note is not None:
            note()

    def close(self) -> dict:
        """Close the writer; returns its final summary."""
        return self.writer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
