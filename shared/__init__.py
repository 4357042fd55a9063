"""Shared core of the train and runtime packages: body model, camera, labels, formats.

Imports only numpy, torch and pyyaml (opencv lazily, for recordings); never ``train`` or
``runtime``.
"""
