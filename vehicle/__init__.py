"""vrsim vehicle package."""
