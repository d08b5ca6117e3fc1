"""Test-wide settings: notebooks run in the smoke profile, artifacts go to a temporary folder."""
import os
import tempfile

os.environ.setdefault("WMTHESIS_PROFILE", "smoke")
os.environ.setdefault("WMTHESIS_DATA", tempfile.mkdtemp(prefix="wmthesis-test-data-"))
os.environ.setdefault("MPLBACKEND", "Agg")
