"""Task classes, one per file."""
