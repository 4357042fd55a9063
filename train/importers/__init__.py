"""Importers of other people's depth data into the project's recordings (``train-import``)."""
