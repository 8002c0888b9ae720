"""The error every dataset tool raises for a folder it cannot use (defined apart so that the reader and the video
decoder it calls both raise it without importing each other)."""

from __future__ import annotations


class DatasetError(ValueError):
    """The folder is not a (readable) surrol_data / LeRobot v3 dataset; the message says what to do."""
