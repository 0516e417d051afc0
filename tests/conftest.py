import sys
from pathlib import Path

import pytest

# tests/analytic.py (the closed-form scenes) is imported by several test modules
sys.path.insert(0, str(Path(__file__).parent))

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="session")
def crf():
    from necviz.core.crf import default_davis346

    return default_davis346()
