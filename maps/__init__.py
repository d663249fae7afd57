"""vrsim maps package."""
