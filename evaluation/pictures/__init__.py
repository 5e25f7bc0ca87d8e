"""Pictures (layer 4)."""
