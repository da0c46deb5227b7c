"""Shared pytest set-up for the rtsim suite.

tests/references.py holds independent minimal-coordinate reference solutions (numpy + scipy only);
make it importable as `references` whatever the import mode or working directory.
"""
from __future__ import annotations

import sys
from pathlib import Path

TESTS_DIR = Path(__file__).resolve().parent
if str(TESTS_DIR) not in sys.path:
    sys.path.insert(0, str(TESTS_DIR))
