"""The one timer of the benchmarks: wall time in milliseconds, synchronized on CUDA.

CUDA kernels run asynchronously, so a timer that does not wait for the device measures the
launch, not the work; on the CPU there is nothing to wait for. The median after a warm-up
(first calls pay for imports, allocator growth and kernel caches) is what every figure here
reports, because these machines are noisy and a mean follows every hiccup.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import torch

__all__ = ["synchronize", "wall_ms", "median_ms", "alternating_median_ms"]


def synchronize(device: str | torch.device = "cpu") -> None:
    """Wait for the work queued on ``device`` (a no-op off CUDA)."""
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def wall_ms(fn: Callable[[], object], device: str | torch.device = "cpu") -> float:
    """Wall time of one ``fn()`` in milliseconds, the device synchronized before and after."""
    synchronize(device)
    t0 = time.perf_counter()
    fn()
    synchronize(device)
    return (time.perf_counter() - t0) * 1e3


def median_ms(
    fn: Callable[[], object],
    repeats: int = 20,
    warmup: int = 3,
    device: str | torch.device = "cpu",
) -> float:
    """Median of :func:`wall_ms` over ``repeats`` calls after ``warmup`` untimed calls.

    ``device`` is where ``fn``'s inputs live: CUDA work is synchronized, CPU work is not.
    """
    for _ in range(warmup):
        fn()
    return statistics.median(wall_ms(fn, device) for _ in range(repeats))


def alternating_median_ms(
    fns: dict[str, Callable[[], object]],
    repeats: int = 20,
    warmup: int = 3,
    device: str | torch.device = "cpu",
) -> dict[str, float]:
    """:func:`median_ms` of several functions timed in turn, one call of each per round, so that
    a slow spell of a noisy host falls on all of them alike: the figures to take ratios of."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            times[name].append(wall_ms(fn, device))
    return {name: statistics.median(t) for name, t in times.items()}
