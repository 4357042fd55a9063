"""Speed figures of the runtime's hot paths (``make bench``), printed, never asserted.

Kept out of ``runtime`` so that the deployable package carries no benchmark code: ``bench``
may import ``shared`` and ``runtime``, never the other way round. Every figure is timed by
:mod:`bench.timing`; the inputs are synthetic (:mod:`bench.scenes`) unless a recording is
given. One module per subject: :mod:`bench.kinematics`, :mod:`bench.tracker`,
:mod:`bench.tracker_terms`, :mod:`bench.forest`, :mod:`bench.segmentation`; :mod:`bench.cli`
prints them all.
"""
