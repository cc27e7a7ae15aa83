"""What ``python -m srmpc stage=...`` runs: one module per stage."""
