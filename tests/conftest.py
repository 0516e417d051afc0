import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

# tests/analytic.py (the closed-form scenes) is imported by several test modules
sys.path.insert(0, str(Path(__file__).parent))

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# demos write the scene cache (necviz.drivers.sim.scene_cache): into a scratch directory, never the user's
if "NECVIZ_CACHE_DIR" not in os.environ:
    os.environ["NECVIZ_CACHE_DIR"] = _cache = tempfile.mkdtemp(prefix="necviz-test-cache-")
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)


@pytest.fixture(scope="session")
def crf():
    from necviz.core.crf import default_davis346

    return default_davis346()
