"""srmpc."""
