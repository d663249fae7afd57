"""vrsim controller package."""
