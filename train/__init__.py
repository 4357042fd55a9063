"""Training pipeline: motion loading and retargeting, synthetic depth rendering, forest
training, evaluation. May import ``shared``; never ``runtime``."""
