"""Typed configuration: the Hydra schema, composition and one-line error reporting."""
