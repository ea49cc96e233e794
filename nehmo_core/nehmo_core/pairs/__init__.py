"""Pair models from robot descriptions: ``nehmo pair build A B`` (:mod:`.build`)."""
