"""surrol_data."""
