"""Run the example's tests from a checkout without installing it: put ``nerfedit_twist.py`` (one folder up) on
``sys.path``. An installed copy (``pip install -e docs/examples/twist``) is the same file."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
