"""Closed-loop controllers: observation (and scene) in, physical action (delta, a) out."""
