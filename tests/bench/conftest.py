"""Tests of what lives in bench/ (the paper's subject and baselines, the bench scripts): bench/ is on sys.path, as it
is for a script run from it."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
