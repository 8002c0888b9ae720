"""Test-session environment: datasets are local, and the Hugging Face caches stay out of the user's home."""

import os
import tempfile
from pathlib import Path

# Set before any test module imports lerobot / datasets (they read these at import); subprocess tests inherit them.
os.environ.setdefault("HF_DATASETS_CACHE", str(Path(tempfile.gettempdir()) / "surrol_data_test_hf_cache"))
os.environ.setdefault("HF_HUB_OFFLINE", "1")


def pytest_configure(config):
    config.addinivalue_line("markers", "browser: needs headless Chromium (apt-get install chromium); skips without it")
