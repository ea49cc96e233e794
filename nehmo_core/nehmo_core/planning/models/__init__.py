"""Pair value models: evaluation, pair frames, the registry of shipped and trained models,
certified margins."""
