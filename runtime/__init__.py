"""Deployable runtime: forest inference, tracker, detector, streams, exporters, CLIs.
May import ``shared``; never ``train``. Installs and runs without pyrender or anny."""
